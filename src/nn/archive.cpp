#include "archive.hpp"

#include <filesystem>
#include <sstream>

#include "skyloop/core/error.hpp"
#include "skyloop/core/io.hpp"

namespace skyloop::nn {

OpenedArchive open_archive(const std::string& path, const ArchiveKind& kind) {
  const std::string name = kind.what + " '" + path + "'";
  if (!std::filesystem::is_regular_file(path)) throw InputError(name + " does not exist: allowed " + kind.allowed);
  OpenedArchive out;
  try {
    out.archive.load_from(path);
  } catch (const std::exception&) {
    throw InputError(name + " is corrupt or not a torch archive: allowed " + kind.allowed);
  }
  c10::IValue raw;
  if (!out.archive.try_read("skyloop_meta", raw) || !raw.isString())
    throw InputError(name + " has no skyloop header: allowed " + kind.allowed);
  try {
    out.meta = nlohmann::json::parse(raw.toStringRef());
  } catch (const std::exception&) {
    throw InputError(name + " has a corrupt header: allowed " + kind.allowed);
  }
  const std::string format = out.meta.value("format", "");
  const int version = out.meta.value("version", 0);
  if (format != kind.format || version != kind.version)
    throw InputError(name + " has format '" + format + "' version " + std::to_string(version) + ": allowed " + kind.format +
                     " version " + std::to_string(kind.version));
  return out;
}

void write_archive(const std::string& path, const ArchiveKind& kind, nlohmann::json meta,
                   torch::serialize::OutputArchive& archive) {
  meta["format"] = kind.format;
  meta["version"] = kind.version;
  archive.write("skyloop_meta", c10::IValue(meta.dump()));
  std::ostringstream bytes;
  archive.save_to(bytes);
  write_file_atomic(path, bytes.str());
}

}  // namespace skyloop::nn
