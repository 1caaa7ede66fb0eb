#pragma once
// A TOML document of the experiments' own files (experiment files, benchmark tasks), parsed with
// one error line on a syntax error. Private to skyloop_experiments (toml++ stays out of the
// public headers).
#include <algorithm>
#include <string>
#include <toml++/toml.h>

#include "skyloop/core/error.hpp"

namespace skyloop {

/// `text` parsed; a syntax error throws InputError "<source>:<line>: invalid TOML: <what>".
inline toml::table parse_toml_document(const std::string& text, const std::string& source) {
  try {
    return toml::parse(text, source);
  } catch (const toml::parse_error& e) {
    std::string d(e.description());
    std::replace(d.begin(), d.end(), '\n', ' ');
    throw InputError(source + ":" + std::to_string(e.source().begin.line) + ": invalid TOML: " + d);
  }
}

}  // namespace skyloop
