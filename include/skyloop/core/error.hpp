#pragma once
// Error kinds. The CLI maps InputError to exit code 2 (bad input: config, arguments, files the
// user gave) and every other std::exception to exit code 1 (runtime failure).
#include <stdexcept>
#include <string>

namespace skyloop {

/// Bad input from the user. The message is one line naming the field, the value and what is
/// allowed, e.g. "channel.p_max_dbm = 400 is out of range: allowed [-30, 60] (dBm)".
class InputError : public std::invalid_argument {
 public:
  explicit InputError(const std::string& what) : std::invalid_argument(what) {}
};

}  // namespace skyloop
