#include "io/compression.h"

#include <fmt/format.h>
#include <zlib.h>

#include <algorithm>

#include "base/error.h"
#include "util/text.h"

namespace vx {

std::vector<unsigned char> deflate_bytes(const void* data, std::size_t size, bool gzip, std::size_t chunk) {
  chunk = std::clamp<std::size_t>(chunk, 1, 1u << 30);  // z_stream counters (avail_in/out) are 32-bit
  z_stream zs{};
  if (deflateInit2(&zs, 6, Z_DEFLATED, gzip ? 15 + 16 : 15, 8, Z_DEFAULT_STRATEGY) != Z_OK)
    throw Error("zlib: cannot start compression");
  // deflateBound takes a uLong (64-bit here); the input is fed in chunks of at most `chunk`
  std::vector<unsigned char> out(std::size_t(deflateBound(&zs, uLong(size))) + 64);
  const auto* in = static_cast<const Bytef*>(data);
  std::size_t done_in = 0, done_out = 0;
  int rc = Z_OK;
  while (rc != Z_STREAM_END) {
    const std::size_t in_chunk = std::min(size - done_in, chunk);
    const bool last = done_in + in_chunk == size;
    zs.next_in = const_cast<Bytef*>(in + done_in);
    zs.avail_in = uInt(in_chunk);
    if (out.size() - done_out < 64) out.resize(out.size() + out.size() / 2 + 4096);
    const std::size_t out_chunk = std::min(out.size() - done_out, chunk);
    zs.next_out = out.data() + done_out;
    zs.avail_out = uInt(out_chunk);
    rc = deflate(&zs, last ? Z_FINISH : Z_NO_FLUSH);
    done_in += in_chunk - zs.avail_in;
    done_out += out_chunk - zs.avail_out;
    if (rc != Z_OK && rc != Z_STREAM_END && rc != Z_BUF_ERROR) break;
  }
  deflateEnd(&zs);
  if (rc != Z_STREAM_END || done_in != size)
    throw Error(fmt::format("zlib: compression failed after {} of {} bytes", done_in, size));
  out.resize(done_out);
  return out;
}

std::vector<char> inflate_bytes(const char* data, std::size_t size, std::size_t expected, const std::filesystem::path& path,
                                std::size_t chunk) {
  chunk = std::clamp<std::size_t>(chunk, 1, 1u << 30);
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
    const std::size_t in_chunk = std::min<std::size_t>(size - done_in, chunk);
    const std::size_t out_chunk = std::min<std::size_t>(expected - done_out, chunk);
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
