#pragma once
// Small text helpers shared by the error messages and listings.
#include <string>
#include <vector>

namespace skyloop {

/// The items joined by `sep` ("a, b, c" by default): how an error line lists what is allowed.
inline std::string join(const std::vector<std::string>& items, const std::string& sep = ", ") {
  std::string out;
  for (const auto& x : items) out += (out.empty() ? "" : sep) + x;
  return out;
}

}  // namespace skyloop
