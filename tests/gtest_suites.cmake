# One CTest test per GoogleTest suite of a test binary (`skyloop_add_gtest_suites` in
# tests/CMakeLists.txt), instead of one per test as gtest_discover_tests does.
#
# Why: every process that links Debian's LibTorch spends about a second before main (the dynamic
# loader resolving 275 libraries, LibTorch registering its operators; BENCHMARKS.md, "The test
# suite's process start-ups"). One process per test made the unit tests' 162 tests cost 162 of those
# seconds; one per suite costs 34. A suite's tests run in one process, as they do when the binary
# is run by hand (and as scripts/test-sanitizers runs them), so they must not rely on a fresh
# process; each test's own pass or failure is still printed by GoogleTest in the output.
#
# Run at build time (POST_BUILD) as a script:
#   cmake -D TEST_EXECUTABLE=... -D CTEST_FILE=... -D WORKING_DIRECTORY=... -D TEST_TIMEOUT=...
#         -D DISCOVERY_TIMEOUT=... [-D ALONE=Suite.TestA,Suite.TestB] -P gtest_suites.cmake
# The tests named in ALONE (long ones) get a CTest test of their own ("Suite.TestA"), so that
# `ctest --parallel` can balance them; the rest of their suite stays one test ("Suite").
# It writes CTEST_FILE, which CTest includes (the directory's TEST_INCLUDE_FILES).

cmake_policy(SET CMP0057 NEW)  # if(... IN_LIST ...)

foreach(var TEST_EXECUTABLE CTEST_FILE WORKING_DIRECTORY TEST_TIMEOUT DISCOVERY_TIMEOUT)
  if(NOT DEFINED ${var})
    message(FATAL_ERROR "gtest_suites.cmake: ${var} is not set")
  endif()
endforeach()

execute_process(
  COMMAND "${TEST_EXECUTABLE}" --gtest_list_tests
  WORKING_DIRECTORY "${WORKING_DIRECTORY}"
  TIMEOUT ${DISCOVERY_TIMEOUT}
  OUTPUT_VARIABLE listing
  ERROR_VARIABLE listing_error
  RESULT_VARIABLE result)
if(NOT result EQUAL 0)
  message(FATAL_ERROR "gtest_suites.cmake: ${TEST_EXECUTABLE} --gtest_list_tests failed (${result}):\n${listing}${listing_error}")
endif()

# A suite line starts in column 0 and ends with '.', possibly followed by a comment
# ("Prefix/Suite.  # TypeParam = ..."); test lines are indented.
string(REPLACE "," ";" alone "${ALONE}")
string(REPLACE ";" "\\;" listing "${listing}")
string(REPLACE "\n" ";" lines "${listing}")
set(script "")
set(names "")
# A test of its own that GoogleTest skipped is reported as skipped; a suite in which one test was
# skipped and the rest passed is reported as passed (GoogleTest's output names the skipped one).
function(add_one name filter properties)
  string(APPEND script
    "add_test([=[${name}]=] [==[${TEST_EXECUTABLE}]==] [==[--gtest_filter=${filter}]==])\n"
    "set_tests_properties([=[${name}]=] PROPERTIES WORKING_DIRECTORY [==[${WORKING_DIRECTORY}]==]"
    " TIMEOUT ${TEST_TIMEOUT}${properties})\n")
  list(APPEND names "${name}")
  set(script "${script}" PARENT_SCOPE)
  set(names "${names}" PARENT_SCOPE)
endfunction()
# The suites in listing order, each with its tests.
set(suites "")
foreach(line IN LISTS lines)
  if(line MATCHES "^([^ #][^ #]*)\\.")
    set(suite "${CMAKE_MATCH_1}")
    list(APPEND suites "${suite}")
    set("tests_of_${suite}" "")
  elseif(line MATCHES "^  ([^ #]+)" AND DEFINED suite)
    list(APPEND "tests_of_${suite}" "${suite}.${CMAKE_MATCH_1}")
  endif()
endforeach()
foreach(listed IN LISTS alone)
  set(found FALSE)
  foreach(suite IN LISTS suites)
    if(listed IN_LIST "tests_of_${suite}")
      set(found TRUE)
    endif()
  endforeach()
  if(NOT found)
    message(FATAL_ERROR "gtest_suites.cmake: ${TEST_EXECUTABLE} has no test ${listed} (ALONE)")
  endif()
endforeach()
foreach(suite IN LISTS suites)
  set(rest "")
  foreach(test IN LISTS "tests_of_${suite}")
    if(test IN_LIST alone)
      add_one("${test}" "${test}" " SKIP_REGULAR_EXPRESSION [==[\\[  SKIPPED \\]]==]")
    else()
      list(APPEND rest "${test}")
    endif()
  endforeach()
  if(rest STREQUAL "")
    continue()
  endif()
  set(filter "${suite}.*")
  if(NOT rest STREQUAL "${tests_of_${suite}}")
    string(REPLACE ";" ":" filter "${rest}")
  endif()
  add_one("${suite}" "${filter}" "")
endforeach()
if(names STREQUAL "")
  message(FATAL_ERROR "gtest_suites.cmake: ${TEST_EXECUTABLE} lists no test suite")
endif()
file(WRITE "${CTEST_FILE}" "${script}")
