#include "archive.hpp"

#include <zlib.h>

#include <cstdint>
#include <filesystem>
#include <sstream>

#include "skyloop/core/error.hpp"
#include "skyloop/core/io.hpp"

namespace skyloop::nn {

namespace {

std::uint32_t crc_of(const unsigned char* p, std::size_t n) {
  return static_cast<std::uint32_t>(::crc32(::crc32(0L, Z_NULL, 0), p, static_cast<uInt>(n)));
}

/// Inflates a raw deflate stream of `size` output bytes; empty optional if it is not one.
bool inflate_raw(const unsigned char* in, std::size_t in_size, std::size_t size, std::string& out) {
  out.assign(size, '\0');
  z_stream z{};
  if (inflateInit2(&z, -MAX_WBITS) != Z_OK) return false;
  z.next_in = const_cast<unsigned char*>(in);
  z.avail_in = static_cast<uInt>(in_size);
  z.next_out = reinterpret_cast<unsigned char*>(out.data());
  z.avail_out = static_cast<uInt>(size);
  const int rc = inflate(&z, Z_FINISH);
  const bool ok = rc == Z_STREAM_END && z.total_out == size;
  inflateEnd(&z);
  return ok;
}

std::uint32_t le(const std::string& b, std::size_t at, int bytes) {
  std::uint32_t v = 0;
  for (int i = bytes - 1; i >= 0; --i) v = (v << 8) | static_cast<unsigned char>(b[at + static_cast<std::size_t>(i)]);
  return v;
}

}  // namespace

std::string verify_zip_checksums(const std::string& bytes) {
  // End of central directory: signature 0x06054b50, at most 64 KiB of comment after it.
  const std::size_t n = bytes.size();
  if (n < 22) return "too short for a torch archive";
  std::size_t eocd = std::string::npos;
  for (std::size_t i = n - 22 + 1; i-- > (n > 22 + 65535 ? n - 22 - 65535 : 0);)
    if (le(bytes, i, 4) == 0x06054b50u) {
      eocd = i;
      break;
    }
  if (eocd == std::string::npos) return "no zip directory (truncated or not a torch archive)";
  const std::size_t entries = le(bytes, eocd + 10, 2);
  std::size_t at = le(bytes, eocd + 16, 4);
  if (entries == 0xFFFF || at == 0xFFFFFFFFu) return {};  // zip64: left to LibTorch's reader
  for (std::size_t e = 0; e < entries; ++e) {
    if (at + 46 > n || le(bytes, at, 4) != 0x02014b50u) return "a corrupt zip directory";
    const std::uint16_t method = static_cast<std::uint16_t>(le(bytes, at + 10, 2));
    const std::uint32_t crc = le(bytes, at + 16, 4), packed = le(bytes, at + 20, 4), size = le(bytes, at + 24, 4);
    const std::size_t name_len = le(bytes, at + 28, 2), extra_len = le(bytes, at + 30, 2), comment_len = le(bytes, at + 32, 2);
    const std::size_t local = le(bytes, at + 42, 4);
    const std::string entry = bytes.substr(at + 46, std::min(name_len, n - std::min(n, at + 46)));
    if (local + 30 > n || le(bytes, local, 4) != 0x04034b50u) return "a corrupt entry header (" + entry + ")";
    const std::size_t data = local + 30 + le(bytes, local + 26, 2) + le(bytes, local + 28, 2);
    if (data + packed > n) return "a truncated entry (" + entry + ")";
    const auto* raw = reinterpret_cast<const unsigned char*>(bytes.data()) + data;
    std::uint32_t got = 0;
    if (method == 0) {  // stored: the tensor data
      got = crc_of(raw, packed);
    } else if (method == 8) {  // deflated: TorchScript code text
      std::string plain;
      if (!inflate_raw(raw, packed, size, plain)) return "an undecodable entry (" + entry + ")";
      got = crc_of(reinterpret_cast<const unsigned char*>(plain.data()), plain.size());
    } else {
      return "an entry of unknown compression (" + entry + ")";
    }
    if (got != crc) return "a checksum mismatch in " + entry;
    at += 46 + name_len + extra_len + comment_len;
  }
  return {};
}

OpenedArchive open_archive(const std::string& path, const ArchiveKind& kind) {
  const std::string name = kind.what + " '" + path + "'";
  if (!std::filesystem::is_regular_file(path)) throw InputError(name + " does not exist: allowed " + kind.allowed);
  const std::string bytes = read_file(path, kind.what);
  // LibTorch's reader does not check the zip format's CRC-32 of each record: a flipped byte in a
  // tensor would load as a silently different model. Every record is verified here first.
  if (const std::string bad = verify_zip_checksums(bytes); !bad.empty())
    throw InputError(name + " is corrupt (" + bad + "): allowed " + kind.allowed);
  OpenedArchive out;
  try {
    std::istringstream in(bytes);
    out.archive.load_from(in);
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
