#include "io/compression.h"

#include <fmt/format.h>
#include <zlib.h>

#include <algorithm>

#include "base/error.h"
#include "util/text.h"

namespace vx {

std::vector<unsigned char> deflate_bytes(const void* data, std::size_t size, bool gzip) {
  z_stream zs{};
  if (deflateInit2(&zs, 6, Z_DEFLATED, gzip ? 15 + 16 : 15, 8, Z_DEFAULT_STRATEGY) != Z_OK)
    throw Error("zlib: cannot start compression");
  std::vector<unsigned char> out(deflateBound(&zs, uLong(size)) + 64);
  zs.next_in = static_cast<Bytef*>(const_cast<void*>(data));
  zs.avail_in = uInt(size);
  zs.next_out = out.data();
  zs.avail_out = uInt(out.size());
  const int rc = deflate(&zs, Z_FINISH);
  const std::size_t produced = zs.total_out;
  deflateEnd(&zs);
  if (rc != Z_STREAM_END) throw Error("zlib: compression failed");
  out.resize(produced);
  return out;
}

std::vector<char> inflate_bytes(const char* data, std::size_t size, std::size_t expected, const std::filesystem::path& path) {
  // deflate shrinks data at most ~1032:1: a header promising more is damaged
  if (double(expected) > 1100.0 * double(size) + 4096.0)
    throw Error(fmt::format("{}: {} bytes of compressed data cannot hold the {} bytes of voxels the header promises "
                            "(damaged header or cut-short file; copy or export it again)",
                            quoted(path), size, expected));
  std::vector<char> out(expected);
  z_stream zs{};
  if (inflateInit2(&zs, 15 + 32) != Z_OK) throw Error("zlib: cannot start decompression");
  std::size_t done_in = 0, done_out = 0;
  int rc = Z_OK;
  // feed in chunks: z_stream counters are 32-bit
  while (rc == Z_OK) {
    const std::size_t in_chunk = std::min<std::size_t>(size - done_in, 1u << 30);
    const std::size_t out_chunk = std::min<std::size_t>(expected - done_out, 1u << 30);
    zs.next_in = reinterpret_cast<Bytef*>(const_cast<char*>(data + done_in));
    zs.avail_in = uInt(in_chunk);
    zs.next_out = reinterpret_cast<Bytef*>(out.data() + done_out);
    zs.avail_out = uInt(out_chunk);
    rc = inflate(&zs, Z_NO_FLUSH);
    done_in += in_chunk - zs.avail_in;
    done_out += out_chunk - zs.avail_out;
    if (rc == Z_OK && in_chunk - zs.avail_in == 0 && out_chunk - zs.avail_out == 0) break;
    if (rc == Z_BUF_ERROR) break;
  }
  inflateEnd(&zs);
  if (done_out != expected || (rc != Z_STREAM_END && rc != Z_OK))
    throw Error(fmt::format("{}: compressed voxel data is damaged or cut short ({}; got {} of {} bytes); copy or "
                            "export the file again",
                            quoted(path), rc == Z_DATA_ERROR ? "invalid data" : "incomplete stream", done_out,
                            expected));
  return out;
}

}  // namespace vx
