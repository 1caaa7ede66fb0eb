#pragma once
// The piece cache of `skyloop reproduce`. Every piece of work (a trained model, a chunk of a
// sweep point's snapshots, a MARL run, a planner evaluation) lives under the run directory at a
// path named by the hash of everything that decides its result: the resolved configuration
// (threads excluded), the methods, the sample range and the bytes of the models it uses. A piece
// whose output exists is reused. Computing one holds an exclusive lock (flock on
// locks/<hash>.lock), so processes sharing the directory (MPI ranks, the shards of a Slurm array,
// two runs started by hand) never compute the same piece twice; the kernel drops the lock of a
// process that dies, and its successor resumes from what the dead one left (checkpoints, or
// nothing: every output is written atomically). A computed piece is sealed (seals/<hash>.json:
// every file under it with its size and hash), and a piece counts as done only while its seal
// holds, so a piece truncated or edited on disk (even at a line boundary, which no CSV reader
// notices) is computed again instead of read.
#include <cstdint>
#include <filesystem>
#include <functional>
#include <iosfwd>
#include <string>

#include "skyloop/core/config.hpp"

namespace skyloop::repro {

std::string hex(std::uint64_t h);
std::uint64_t hash_text(const std::string& s, std::uint64_t h = 0xcbf29ce484222325ULL);

/// The configuration text that decides a result: threads never change one.
std::string config_key(Config c);
/// What decides a trained beamformer: everything but the trajectory-level sections.
std::string training_key(Config c);

class PieceCache {
 public:
  explicit PieceCache(std::filesystem::path root) : root_(std::move(root)) {}
  const std::filesystem::path& root() const { return root_; }

  /// Makes sure the piece `id` exists: returns false at once when done() says so and its seal
  /// holds; otherwise takes the piece's lock (waiting while another process holds it, with one
  /// line to `log`), checks again, runs compute() and seals the piece. Returns true when this call
  /// computed it.
  bool ensure(const std::string& id, const std::function<bool()>& done, const std::function<void()>& compute,
              std::ostream* log) const;

  /// Whether the piece's seal exists and every file it lists (under root/id) still has the size
  /// and hash it was sealed with. Files added under the piece since are not checked.
  bool sealed(const std::string& id) const;
  /// Seals the piece: every regular file under root/id (temporaries aside).
  void seal(const std::string& id) const;

 private:
  std::filesystem::path root_;
};

}  // namespace skyloop::repro
