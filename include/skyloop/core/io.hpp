#pragma once
#include <string>

namespace skyloop {

/// Writes `content` to `path` atomically: a temporary file beside it, flushed, then renamed over
/// the target, so a reader never sees a half-written file and an old file survives a failure.
/// Creates missing parent directories. Throws std::runtime_error naming the path on failure.
void write_file_atomic(const std::string& path, const std::string& content);

/// Reads a whole file; throws InputError naming the path if it cannot be read.
std::string read_file(const std::string& path, const std::string& what = "file");

/// Shortest decimal text that reads back to exactly `x` (for CSV, TOML and JSON output).
std::string format_double(double x);

}  // namespace skyloop
