#pragma once
// TOML loading, --set overrides and printing of the Config. Implemented in the skyloop_config
// target (toml++ stays private to it).
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "skyloop/core/config.hpp"

namespace skyloop {

/// Applies a TOML document to `cfg`. Every key must be a known field ("section.name"); an unknown
/// key, a wrong type or an out-of-range value throws InputError with one line naming the key,
/// the value and what is allowed. `source` names the document in messages (a path).
void apply_toml(Config& cfg, const std::string& toml_text, const std::string& source);

/// Applies one "section.name=value" override. The value is read as a TOML value (numbers, lists
/// such as [[20,20],[20,180]], quoted strings); a bare word is taken as a string.
void apply_override(Config& cfg, const std::string& assignment);

/// Defaults, then the file at `path` (if given), then the overrides in order; then validate().
Config resolve_config(const std::optional<std::string>& path, const std::vector<std::string>& overrides);

/// Reads a TOML document whose every key is a list of [x, y] pairs (a scenario file). A key not
/// in `allowed`, a missing or empty list, or an item that is not a pair of numbers throws
/// InputError naming `source` and the key. Returns the lists in the order of `allowed`.
std::vector<std::vector<Point2>> read_point_lists(const std::string& toml_text, const std::string& source,
                                                  const std::vector<std::string>& allowed);

/// Points as Positions [n x 2], each checked to lie in the configured area; an outside point throws
/// InputError "<what>[i] = [x, y] is outside the area: allowed x in [0, ..], y in [0, ..]".
Positions positions_in_area(const std::vector<Point2>& pts, const Config& cfg, const std::string& what);

/// A seed given on the command line (`flag` names it in errors): decimal digits only, in the range
/// of run.seed, [0, 2^62]. Anything else (a sign, letters, trailing text, a value past the range)
/// throws InputError "--seed = '-1' is invalid: allowed an integer in [0, 4611686018427387904]".
std::uint64_t parse_seed(const std::string& flag, const std::string& text);
/// With env.users_file set: scenario.users = the file's user count (read and checked here), so that
/// every config and report states the K the environment has. resolve_config calls it.
void finalise_users_file(Config& cfg);
/// A whole number in [lo, hi] given on the command line as `flag`: digits only (no sign, no
/// fraction, not empty); throws InputError "<flag> = '<text>' is invalid: allowed an integer in [lo, hi]".
std::uint64_t parse_count(const std::string& flag, const std::string& text, std::uint64_t lo, std::uint64_t hi);

/// The whole configuration as TOML, one commented line per field; apply_toml() reads it back
/// to the same Config.
std::string to_toml(const Config& cfg);

}  // namespace skyloop
