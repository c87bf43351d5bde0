// The pixel pass of the DICOM series reader: file by file, each frame decoded (DCMTK, with the
// codecs dicom_common.cpp registers), turned into HU and copied (or, for a tilted series,
// sheared) straight into its slice of the float volume, so memory stays at about the volume's.

#include <dcmtk/config/osconfig.h>
#include <dcmtk/dcmdata/dcdeftag.h>
#include <dcmtk/dcmdata/dcfilefo.h>
#include <dcmtk/dcmdata/dcpixel.h>
#include <dcmtk/dcmdata/dcpixseq.h>
#include <dcmtk/dcmdata/dcpxitem.h>
#include <dcmtk/dcmdata/dcxfer.h>
#include <fmt/format.h>

#include <algorithm>
#include <cstdint>
#include <new>

#include "base/error.h"
#include "io/dicom_common.h"
#include "io/dicom_series_parts.h"
#include "util/progress.h"
#include "util/system_memory.h"
#include "util/text.h"

namespace vx::dicom {
namespace {

/// Stored pixel values of one frame to HU, written into `out` (rows x cols, column fastest).
void frame_to_hu(const FileInfo& f, const FrameInfo& fr, const std::vector<Uint8>& buffer, float* out) {
  const std::size_t n = std::size_t(f.rows) * std::size_t(f.cols);
  const int shift = std::max(0, f.high_bit + 1 - f.bits_stored);
  const int bits = std::clamp(f.bits_stored, 1, 32);
  const std::uint64_t mask = (std::uint64_t(1) << bits) - 1;
  const std::int64_t sign_bit = std::int64_t(1) << (bits - 1);
  const long pad_lo = f.has_padding_limit ? std::min(f.padding, f.padding_limit) : f.padding;
  const long pad_hi = f.has_padding_limit ? std::max(f.padding, f.padding_limit) : f.padding;
  for (std::size_t p = 0; p < n; ++p) {
    std::uint64_t raw = 0;
    switch (f.bits_allocated) {
      case 8: raw = buffer[p]; break;
      case 16: raw = reinterpret_cast<const Uint16*>(buffer.data())[p]; break;
      default: raw = reinterpret_cast<const Uint32*>(buffer.data())[p]; break;
    }
    std::int64_t v = std::int64_t((raw >> shift) & mask);
    if (f.pixel_rep == 1 && (v & sign_bit)) v -= std::int64_t(1) << bits;
    if (f.has_padding && v >= pad_lo && v <= pad_hi) {
      out[p] = kAirHu;
    } else if (!f.lut.empty()) {
      const std::int64_t e = std::clamp<std::int64_t>(v - f.lut_first, 0, std::int64_t(f.lut.size()) - 1);
      out[p] = float(f.lut[std::size_t(e)]);
    } else {
      out[p] = float(double(v) * fr.slope + fr.intercept);
    }
  }
}

/// Copies (or, for a tilted series, shears) one frame of HU values into slice k of the volume.
void place_slice(const SliceLayout& layout, int k, int rows, int cols, const float* slice, Volume& volume) {
  const Eigen::Vector3i& d = volume.geometry.dims;
  float* out = volume.hu.data() + std::size_t(k) * std::size_t(d.x()) * std::size_t(d.y());
  if (!layout.tilted) {
    std::copy(slice, slice + std::size_t(rows) * std::size_t(cols), out);
    return;
  }
  const Eigen::Vector2d s = layout.shift[std::size_t(k)];
  for (int j = 0; j < d.y(); ++j)
    for (int i = 0; i < d.x(); ++i) {
      // bilinear sample of the input slice; beyond half a pixel outside it is air
      double x = i + layout.offset.x() - s.x(), y = j + layout.offset.y() - s.y();
      float& v = out[std::size_t(i) + std::size_t(d.x()) * std::size_t(j)];
      if (x < -0.5 || y < -0.5 || x > cols - 0.5 || y > rows - 0.5) {
        v = kAirHu;
        continue;
      }
      x = std::clamp(x, 0.0, double(cols - 1));
      y = std::clamp(y, 0.0, double(rows - 1));
      const int x0 = std::min(int(x), cols - 2 < 0 ? 0 : cols - 2), y0 = std::min(int(y), rows - 2 < 0 ? 0 : rows - 2);
      const int x1 = std::min(x0 + 1, cols - 1), y1 = std::min(y0 + 1, rows - 1);
      const double fx = x - x0, fy = y - y0;
      auto at = [&](int xx, int yy) { return double(slice[std::size_t(xx) + std::size_t(cols) * std::size_t(yy)]); };
      v = float((1 - fy) * ((1 - fx) * at(x0, y0) + fx * at(x1, y0)) + fy * ((1 - fx) * at(x0, y1) + fx * at(x1, y1)));
    }
}

/// RLE Lossless (PS3.5 annex G) frames are checked before DCMTK decodes them: DCMTK 3.6.7's
/// decoder trusts the segment offsets of each fragment's 64-byte header, and an offset beyond the
/// fragment (or before the previous one) made it read far outside its buffer (a SIGSEGV, found by
/// the fuzz target fuzz_dicom_series once single-image series were read). Each frame is one
/// fragment (after the offset table): at least 64 bytes, as many segments as bytes per pixel
/// (samples x bytes per sample, 1..15), the first at 64, each after the previous and inside it.
void check_rle_fragments(const FileInfo& f, DcmDataset* ds, DcmPixelData* pixels) {
  DcmPixelSequence* seq = nullptr;
  if (pixels->getEncapsulatedRepresentation(ds->getOriginalXfer(), nullptr, seq).bad() || !seq)
    throw Error(fmt::format("DICOM: {} is RLE compressed but holds no encapsulated pixel data; the file is corrupt",
                            quoted(f.path)));
  const unsigned long items = seq->card();
  if (items < 1 + f.frames.size())
    throw Error(
        fmt::format("DICOM: {} is RLE compressed with {} fragment(s) for {} frame(s) (one per frame after the "
                    "offset table); the file is truncated or corrupt",
                    quoted(f.path), items == 0 ? 0 : items - 1, f.frames.size()));
  const std::uint32_t expected = std::uint32_t(std::max(f.samples, 1) * std::max(f.bits_allocated / 8, 1));
  for (unsigned long i = 1; i < items; ++i) {
    DcmPixelItem* item = nullptr;
    Uint8* data = nullptr;
    if (seq->getItem(item, i).bad() || !item || item->getUint8Array(data).bad())
      throw Error(fmt::format("DICOM: {}: RLE fragment {} cannot be read; the file is corrupt", quoted(f.path), i));
    const Uint32 length = item->getLength();
    const auto bad = [&](const std::string& why) {
      return Error(fmt::format("DICOM: {}: RLE fragment {} is corrupt ({}); the file cannot be decoded, re-export it",
                               quoted(f.path), i, why));
    };
    if (length < 64 || !data) throw bad(fmt::format("{} bytes, less than its 64-byte header", length));
    const auto word = [&](int k) {
      return std::uint32_t(data[4 * k]) | std::uint32_t(data[4 * k + 1]) << 8 | std::uint32_t(data[4 * k + 2]) << 16 |
             std::uint32_t(data[4 * k + 3]) << 24;
    };
    const std::uint32_t segments = word(0);
    if (segments < 1 || segments > 15 || segments != expected)
      throw bad(fmt::format("{} segments, {} expected for {} sample(s) of {} bits", segments, expected, f.samples,
                            f.bits_allocated));
    if (word(1) != 64) throw bad(fmt::format("the first segment starts at {}, not 64", word(1)));
    for (std::uint32_t k = 1; k <= segments; ++k) {
      const std::uint32_t end = k < segments ? word(int(k) + 1) : std::uint32_t(length);
      if (end <= word(int(k)) || end > length)
        throw bad(fmt::format("segment {} spans bytes {} to {} of {}", k, word(int(k)), end, length));
    }
  }
}

}  // namespace

Volume allocate_volume(const SliceLayout& layout, const SeriesInfo& series, std::uint64_t max_bytes) {
  Volume volume;
  volume.geometry = layout.geometry;
  const Eigen::Vector3i& dims = volume.geometry.dims;
  const std::int64_t voxels = volume.geometry.voxel_count();
  // Linux hands out more than it has and kills the process when the pages are touched: ask
  // first. A compressed frame can declare any image size in a few bytes, and a tilted
  // series' grid grows with the slices' drift, so a damaged header lands here.
  const std::uint64_t limit = max_bytes > 0 ? max_bytes : physical_memory_bytes() / 2;
  const double bytes = double(voxels) * double(sizeof(float));
  if (limit > 0 && bytes > double(limit))
    throw Error(
        fmt::format("DICOM: series {} would become a {} x {} x {} volume ({:.0f} MB as float HU), more than {} "
                    "({:.0f} MB); its Rows / Columns, NumberOfFrames or slice positions are likely damaged. "
                    "A scan that really is this large must be cropped or downsampled before converting",
                    series.uid, dims.x(), dims.y(), dims.z(), bytes * 1e-6,
                    max_bytes > 0 ? "the limit set" : "half this machine's memory", double(limit) * 1e-6));
  try {
    volume.hu.assign(std::size_t(voxels), kAirHu);
  } catch (const std::bad_alloc&) {
    throw Error(fmt::format("DICOM: not enough memory for the {} x {} x {} volume of series {} ({:.0f} MB)", dims.x(),
                            dims.y(), dims.z(), series.uid, bytes * 1e-6));
  }
  return volume;
}

void read_pixels(const std::vector<FileInfo>& files, const std::vector<FrameInfo>& frames, const SliceLayout& layout,
                 Volume& volume) {
  std::vector<std::vector<std::pair<int, int>>> by_file(files.size());  // (frame, slice)
  for (std::size_t k = 0; k < frames.size(); ++k) by_file[frames[k].file].emplace_back(frames[k].frame, int(k));
  std::vector<const FrameInfo*> frame_of_slice(frames.size());
  for (std::size_t k = 0; k < frames.size(); ++k) frame_of_slice[k] = &frames[k];
  std::vector<std::size_t> file_order;
  for (std::size_t i = 0; i < files.size(); ++i)
    if (!by_file[i].empty()) file_order.push_back(i);
  std::sort(file_order.begin(), file_order.end(), [&](std::size_t a, std::size_t b) {
    return by_file[a].front().second < by_file[b].front().second;  // roughly slice order
  });
  Progress progress("Reading DICOM slices", frames.size() >= kProgressFrom);
  std::vector<Uint8> buffer;
  std::vector<float> slice_hu;
  std::size_t done = 0;
  for (std::size_t fi : file_order) {
    const FileInfo& f = files[fi];
    auto& list = by_file[fi];
    std::sort(list.begin(), list.end());
    DcmFileFormat ff;
    OFCondition status = ff.loadFile(f.path.c_str(), EXS_Unknown, EGL_noChange, kHeaderReadLimit, ERM_autoDetect);
    if (status.bad())
      throw Error(fmt::format("DICOM: cannot read {} (it changed since its header was read?): {}", quoted(f.path),
                              status.text()));
    DcmDataset* ds = ff.getDataset();
    DcmElement* element = nullptr;
    if (ds->findAndGetElement(DCM_PixelData, element).bad() || !element)
      throw Error(fmt::format("DICOM: {} has no pixel data element (7FE0,0010)", quoted(f.path)));
    auto* pixels = dynamic_cast<DcmPixelData*>(element);
    if (!pixels) throw Error(fmt::format("DICOM: {} has a malformed pixel data element", quoted(f.path)));
    Uint32 frame_size = 0;
    status = pixels->getUncompressedFrameSize(ds, frame_size);
    const std::size_t needed = std::size_t(f.rows) * std::size_t(f.cols) * std::size_t(f.bits_allocated / 8);
    if (status.bad() || frame_size < needed)
      throw Error(fmt::format("DICOM: {}: cannot work out the size of a frame ({})", quoted(f.path),
                              status.bad() ? status.text() : "too small"));
    if (DcmXfer(ds->getOriginalXfer()).getXfer() == EXS_RLELossless) check_rle_fragments(f, ds, pixels);
    buffer.assign(std::size_t(frame_size) + 8, 0);
    slice_hu.resize(std::size_t(f.rows) * std::size_t(f.cols));
    Uint32 start_fragment = 0;
    for (const auto& [frame, k] : list) {
      OFString color_model;
      if (frame > 0 && !DcmXfer(ds->getOriginalXfer()).isEncapsulated()) start_fragment = 0;
      status = pixels->getUncompressedFrame(ds, Uint32(frame), start_fragment, buffer.data(), frame_size, color_model);
      if (status.bad())
        throw Error(
            fmt::format("DICOM: cannot decode {}{}: {} (the file may be truncated or its compressed data "
                        "corrupt; transfer syntax {})",
                        quoted(f.path), f.frames.size() > 1 ? fmt::format(" frame {}", frame + 1) : "", status.text(),
                        f.xfer_name));
      frame_to_hu(f, *frame_of_slice[std::size_t(k)], buffer, slice_hu.data());
      place_slice(layout, k, f.rows, f.cols, slice_hu.data(), volume);
      progress.update(double(++done) / double(frames.size()));
    }
  }
  progress.done();
}

}  // namespace vx::dicom
