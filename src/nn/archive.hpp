#pragma once
// A skyloop torch archive: a JSON header ("skyloop_meta": format, version, ...) beside named
// sub-archives (networks, optimiser state). The beamformer checkpoints (src/nn) and the MARL
// policies (src/marl) are both stored this way.
#include <nlohmann/json.hpp>
#include <string>

#include "torch_fwd.hpp"

namespace skyloop::nn {

/// What a file must be, for checks and messages: e.g. {"policy", "a policy.pt written by
/// `skyloop train`", "skyloop-marl", 1}.
struct ArchiveKind {
  std::string what;     // "checkpoint", "policy"
  std::string allowed;  // what the user should pass instead
  std::string format;
  int version = 0;
};

struct OpenedArchive {
  torch::serialize::InputArchive archive;
  nlohmann::json meta;
};

/// Opens `path` and reads and checks its header. A missing, corrupt or foreign file, or another
/// format or version, throws InputError naming the path and what is allowed.
OpenedArchive open_archive(const std::string& path, const ArchiveKind& kind);

/// Checks every record of a torch archive (a zip of stored records) against the CRC-32 the zip
/// directory holds for it. Returns "" when all match, else what is wrong ("a checksum mismatch in
/// archive/data/3"). Zip64 archives (over 4 GiB) are not checked here.
std::string verify_zip_checksums(const std::string& bytes);

/// Adds the header (`meta` with kind's format and version) to `archive` and writes it atomically.
void write_archive(const std::string& path, const ArchiveKind& kind, nlohmann::json meta,
                   torch::serialize::OutputArchive& archive);

}  // namespace skyloop::nn
