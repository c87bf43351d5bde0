// The header pass of the DICOM series reader: everything about one file but its pixel values.
// Each file is loaded with a read-length limit, so pixel data stays on disk; the header is read
// in stages (declared lengths, identity, transfer syntax, image layout, frame count, then each
// frame's geometry and rescale), each of which can find the file broken and say why.

#include <dcmtk/config/osconfig.h>
#include <dcmtk/dcmdata/dccodec.h>
#include <dcmtk/dcmdata/dcdeftag.h>
#include <dcmtk/dcmdata/dcfilefo.h>
#include <dcmtk/dcmdata/dcmetinf.h>
#include <dcmtk/dcmdata/dcpixel.h>
#include <dcmtk/dcmdata/dcpixseq.h>
#include <dcmtk/dcmdata/dcpxitem.h>
#include <dcmtk/dcmdata/dcspchrs.h>
#include <dcmtk/dcmdata/dcstack.h>
#include <dcmtk/dcmdata/dcuid.h>
#include <dcmtk/dcmdata/dcxfer.h>
#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>

#include "io/dicom_common.h"
#include "io/dicom_series_parts.h"
#include "util/progress.h"
#include "util/text.h"

namespace vx::dicom {
namespace fs = std::filesystem;

/// `s` fit for a terminal: control characters (escape sequences from a hostile file) become '?'.
std::string printable(std::string s) {
  for (char& c : s)
    if ((static_cast<unsigned char>(c) < 0x20 && c != '\t') || c == 0x7f) c = '?';
  return s;
}

namespace {

std::string get_string(DcmItem* item, const DcmTagKey& tag) {
  // text values are short; a longer one is damaged and is not loaded (it would be allocated)
  constexpr Uint32 kMaxText = 1 << 16;
  DcmElement* e = nullptr;
  OFString s;
  if (item && item->findAndGetElement(tag, e).good() && e && e->getLengthField() <= kMaxText &&
      e->getOFStringArray(s).good())
    return std::string(s.c_str());
  return {};
}

bool get_int(DcmItem* item, const DcmTagKey& tag, long& out) {
  if (!item) return false;
  Uint16 u = 0;
  if (item->findAndGetUint16(tag, u).good()) return out = u, true;
  Sint16 s = 0;
  if (item->findAndGetSint16(tag, s).good()) return out = s, true;
  Sint32 i = 0;
  if (item->findAndGetSint32(tag, i).good()) return out = i, true;
  Float64 f = 0;
  if (item->findAndGetFloat64(tag, f).good()) return out = long(std::lround(f)), true;
  return false;
}

/// A text element in UTF-8: converted from the data set's Specific Character Set (0008,0005)
/// when it names one; as stored otherwise or when the conversion fails.
std::string get_text_utf8(DcmItem* item, const DcmTagKey& tag) {
  std::string value = trim(get_string(item, tag));
  OFString charset;
  if (value.empty() || !item || item->findAndGetOFStringArray(DCM_SpecificCharacterSet, charset).bad() ||
      charset.empty())
    return printable(value);
  DcmSpecificCharacterSet converter;
  OFString utf8;
  if (converter.selectCharacterSet(charset).good() && converter.convertString(value.c_str(), utf8).good())
    value = utf8.c_str();
  return printable(value);
}

/// Value `i` of a US or SS element, as stored.
bool get_int_at(DcmItem* item, const DcmTagKey& tag, unsigned long i, long& out) {
  Uint16 u = 0;
  if (item->findAndGetUint16(tag, u, i).good()) return out = u, true;
  Sint16 s = 0;
  if (item->findAndGetSint16(tag, s, i).good()) return out = s, true;
  OFString text;  // other encodings of the value (a string VR, say)
  if (item->findAndGetOFString(tag, text, i).good()) {
    char* end = nullptr;
    const long v = std::strtol(text.c_str(), &end, 10);
    if (end != text.c_str() && *end == '\0' && v >= -32768 && v <= 65535) return out = v, true;
  }
  return false;
}

/// The Modality LUT Sequence of `ds`, if any, into `f` (stored values must be known: pixel_rep).
/// Returns "" or what is wrong with it.
std::string read_modality_lut(DcmItem* ds, FileInfo& f) {
  DcmItem* item = nullptr;
  if (ds->findAndGetSequenceItem(DCM_ModalityLUTSequence, item, 0).bad() || !item) return "";
  long entries = 0, first = 0, bits = 0;
  if (!get_int_at(item, DCM_LUTDescriptor, 0, entries) || !get_int_at(item, DCM_LUTDescriptor, 1, first) ||
      !get_int_at(item, DCM_LUTDescriptor, 2, bits))
    return "its Modality LUT Sequence has no complete LUTDescriptor (0028,3002)";
  if (entries <= 0) entries += 65536;  // 0 means 2^16 entries (also when read as SS)
  if (f.pixel_rep == 1 && first >= 0x8000) first -= 0x10000;
  if (f.pixel_rep == 0 && first < 0) first += 0x10000;
  if (bits != 8 && bits != 16) return fmt::format("its Modality LUT has {} bits per entry (8 or 16 are defined)", bits);
  const Uint16* words = nullptr;
  unsigned long count = 0;
  if (item->findAndGetUint16Array(DCM_LUTData, words, &count).bad() || !words)
    return "its Modality LUT Sequence has no LUTData (0028,3006)";
  f.lut.resize(std::size_t(entries));
  if (count >= std::size_t(entries)) {
    for (long e = 0; e < entries; ++e) f.lut[std::size_t(e)] = words[e];
  } else if (bits == 8 && 2 * count >= std::size_t(entries)) {
    // 8-bit entries packed two to a word, the first in the low byte
    for (long e = 0; e < entries; ++e) f.lut[std::size_t(e)] = (words[e / 2] >> (8 * (e % 2))) & 0xFF;
  } else {
    f.lut.clear();
    return fmt::format("its Modality LUT declares {} entries but holds {}", entries, count);
  }
  f.lut_first = first;
  return "";
}

bool get_doubles(DcmItem* item, const DcmTagKey& tag, double* out, int n) {
  if (!item) return false;
  for (int i = 0; i < n; ++i) {
    Float64 v = 0;
    if (item->findAndGetFloat64(tag, v, unsigned(i)).bad() || !std::isfinite(v)) return false;
    out[i] = v;
  }
  return true;
}

/// The item holding `attr`: inside functional group macro `macro` of the per-frame item, else
/// of the shared item, else the top level of the data set (classic images); null if absent.
DcmItem* find_functional(DcmItem* top, DcmItem* per_frame, DcmItem* shared, const DcmTagKey& macro,
                         const DcmTagKey& attr) {
  for (DcmItem* group : {per_frame, shared}) {
    if (!group) continue;
    DcmItem* m = nullptr;
    if (group->findAndGetSequenceItem(macro, m, 0).good() && m && m->tagExists(attr)) return m;
  }
  return top->tagExists(attr) ? top : nullptr;
}

bool is_ct_sop_class(const std::string& uid) {
  return uid == UID_CTImageStorage || uid == UID_EnhancedCTImageStorage ||
         uid == UID_LegacyConvertedEnhancedCTImageStorage;
}

/// Bytes of one uncompressed frame of `f`.
double frame_bytes(const FileInfo& f) {
  return double(f.rows) * double(f.cols) * double(std::max(f.samples, 1)) * double(std::max(f.bits_allocated, 1)) / 8.0;
}

/// "" when `held` bytes (what the pixel data holds, or at most decodes to) take `frames` frames
/// of `f`'s size, else what is wrong (`holds`: how the data is said to hold them; `why`: the
/// likely cause).
std::string check_frames_fit(const FileInfo& f, long frames, double held, const char* holds, const char* why) {
  const double needed = double(frames) * frame_bytes(f);
  if (needed <= held) return "";
  return fmt::format("it declares {} frame{} of {} x {} pixels ({:.0f} bytes) but its {} {:.0f} bytes ({})", frames,
                     frames == 1 ? "" : "s", f.cols, f.rows, needed, holds, held, why);
}

/// "" when the pixel data holds `frames` frames of the file's size (and the per-frame
/// functional groups describe them all), else what is wrong.
std::string check_frame_count(DcmDataset* ds, const FileInfo& f, long frames, DcmSequenceOfItems* per_frame_seq) {
  if (per_frame_seq && long(per_frame_seq->card()) < frames)
    return fmt::format("it declares {} frames (NumberOfFrames) but its per-frame functional groups describe {}", frames,
                       per_frame_seq->card());
  DcmElement* element = nullptr;
  if (ds->findAndGetElement(DCM_PixelData, element).bad() || !element) return "";
  const DcmXfer xfer(ds->getOriginalXfer());
  if (xfer.isEncapsulated()) {
    // one fragment at least per frame, after the offset table
    auto* pixels = dynamic_cast<DcmPixelData*>(element);
    DcmPixelSequence* sequence = nullptr;
    if (!pixels || pixels->getEncapsulatedRepresentation(xfer.getXfer(), nullptr, sequence).bad() || !sequence)
      return "its compressed pixel data has no fragments";
    const long fragments = long(sequence->card()) - 1;
    if (fragments < frames)
      return fmt::format("it declares {} frames but its compressed pixel data holds {} fragment{}", frames,
                         std::max(0L, fragments), fragments == 1 ? "" : "s");
    if (xfer.getXfer() == EXS_RLELossless) {
      // an RLE run turns 2 bytes into at most 128, after a 64-byte header per frame: a header
      // promising more than 64 times the data is damaged (found by fuzzing: a few bytes declared
      // a 1.7 GB image)
      double most = 0.0;
      for (unsigned long i = 1; i < sequence->card(); ++i) {
        DcmPixelItem* item = nullptr;
        if (sequence->getItem(item, i).good() && item) most += 64.0 * std::max(0.0, double(item->getLength()) - 64.0);
      }
      return check_frames_fit(f, frames, most, "RLE data can hold at most", "Rows / Columns or the data are damaged");
    }
    return "";
  }
  return check_frames_fit(f, frames, double(element->getLengthField()), "pixel data holds",
                          "the file is damaged or cut short");
}

/// Marks `f` as `kind` for `problem`; returns false, so a stage can `return fail(...)`.
bool fail(FileInfo& f, FileKind kind, std::string problem) {
  f.kind = kind;
  f.problem = std::move(problem);
  return false;
}

/// A value longer than the whole file is a damaged length: reading it (values beyond the read
/// limit load on first access) would allocate that much, up to 4 GB (found by fuzzing). False
/// (and `f` broken or not DICOM) when an element of `ds` declares one.
bool check_declared_lengths(DcmDataset* ds, const fs::path& path, bool magic, FileInfo& f) {
  if (!ds) return true;
  const std::uintmax_t file_bytes = [&] {
    std::error_code ec;
    const auto n = fs::file_size(path, ec);
    return ec ? std::uintmax_t(0) : n;
  }();
  DcmStack stack;
  while (ds->nextObject(stack, OFTrue).good()) {
    DcmObject* o = stack.top();
    // the length field as read (getLength() would load the value to measure it)
    const Uint32 declared = o ? o->getLengthField() : 0;
    if (!o || !o->isLeaf() || declared == DCM_UndefinedLength || std::uintmax_t(declared) <= file_bytes) continue;
    // a broken DICOM file, or no DICOM at all (a text file read as a data set): without the
    // 'DICM' marker, only a SOP Class or Series UID of a sane length makes it DICOM
    bool uid_elements = false;
    if (!magic)
      for (const DcmTagKey& tag : {DCM_SOPClassUID, DCM_SeriesInstanceUID}) {
        DcmElement* e = nullptr;
        if (ds->findAndGetElement(tag, e).good() && e && e->getLengthField() > 0 &&
            e->getLengthField() != DCM_UndefinedLength && std::uintmax_t(e->getLengthField()) <= file_bytes)
          uid_elements = true;
      }
    const std::string what = fmt::format(
        "element ({:04x},{:04x}) declares {} bytes, more than the whole file "
        "({} bytes)",
        o->getGTag(), o->getETag(), declared, file_bytes);
    if (magic || uid_elements) return fail(f, FileKind::broken, "it is truncated or damaged: " + what);
    return fail(f, FileKind::not_dicom,
                "it is not a DICOM file (no 'DICM' marker, and read as a DICOM data set its " + what + ")");
  }
  return true;
}

/// Is it DICOM at all (and did it load)? Reads the UIDs, modality and description; false (and
/// `f` broken or not DICOM) otherwise.
bool read_identity(DcmDataset* ds, const OFCondition& status, bool magic, FileInfo& f) {
  f.sop_class = trim(get_string(ds, DCM_SOPClassUID));
  f.series_uid = printable(trim(get_string(ds, DCM_SeriesInstanceUID)));
  const bool looks_dicom = magic || !f.sop_class.empty() || !f.series_uid.empty();
  if (status.bad())
    return looks_dicom
               ? fail(f, FileKind::broken, fmt::format("it is truncated or corrupt (DCMTK: {})", status.text()))
               : fail(f, FileKind::not_dicom, "it is not a DICOM file (no 'DICM' marker and no DICOM data set)");
  if (!looks_dicom)
    return fail(f, FileKind::not_dicom, "it is not a DICOM file (no 'DICM' marker and no SOP Class UID)");
  f.sop_instance = trim(get_string(ds, DCM_SOPInstanceUID));
  f.modality = printable(trim(get_string(ds, DCM_Modality)));
  f.description = get_text_utf8(ds, DCM_SeriesDescription);
  f.is_ct = is_ct_sop_class(f.sop_class);
  return true;
}

/// The transfer syntax, and whether DCMTK can decode it here.
void read_transfer_syntax(DcmFileFormat& ff, DcmDataset* ds, FileInfo& f) {
  f.xfer_uid = trim(get_string(ff.getMetaInfo(), DCM_TransferSyntaxUID));
  const DcmXfer xfer(ds->getOriginalXfer());
  f.xfer_name = xfer.getXferName();
  if (f.xfer_uid.empty()) f.xfer_uid = xfer.getXferID();
  if (xfer.getXfer() == EXS_Unknown) {
    f.xfer_decodable = false;
    f.xfer_name = "an unknown transfer syntax";
  } else if (xfer.isEncapsulated()) {
    f.xfer_decodable = DcmCodecList::canChangeCoding(xfer.getXfer(), EXS_LittleEndianExplicit);
  }
}

/// Is it an image? Its size, pixel format, padding, localizer flag and Modality LUT; false
/// when it is no image (`f` non_image) or a broken one.
bool read_image_layout(DcmDataset* ds, FileInfo& f) {
  long value = 0;
  const bool has_rows = ds->tagExists(DCM_Rows);
  if (!ds->tagExists(DCM_PixelData)) {
    if (has_rows || f.is_ct) return fail(f, FileKind::broken, "it has no pixel data element (7FE0,0010)");
    f.kind = FileKind::non_image;  // DICOMDIR, structured report, presentation state, ...
    return false;
  }
  f.kind = FileKind::image;
  auto require = [&](const DcmTagKey& tag, const char* name, int& out) {
    if (!get_int(ds, tag, value)) return fail(f, FileKind::broken, fmt::format("it has no {} element", name));
    out = int(value);
    return true;
  };
  if (!require(DCM_Rows, "Rows (0028,0010)", f.rows) || !require(DCM_Columns, "Columns (0028,0011)", f.cols) ||
      !require(DCM_BitsAllocated, "BitsAllocated (0028,0100)", f.bits_allocated))
    return false;
  f.bits_stored = get_int(ds, DCM_BitsStored, value) ? int(value) : f.bits_allocated;
  f.high_bit = get_int(ds, DCM_HighBit, value) ? int(value) : f.bits_stored - 1;
  f.pixel_rep = get_int(ds, DCM_PixelRepresentation, value) ? int(value) : 0;
  f.samples = get_int(ds, DCM_SamplesPerPixel, value) ? int(value) : 1;
  f.photometric = trim(get_string(ds, DCM_PhotometricInterpretation));
  if (f.rows <= 0 || f.cols <= 0)
    return fail(f, FileKind::broken, fmt::format("it has an empty image ({} rows x {} columns)", f.rows, f.cols));
  // padding, kept as signed stored values
  auto as_stored = [&](long raw) {
    if (f.pixel_rep == 1 && f.bits_allocated == 16 && raw >= 0x8000) return raw - 0x10000;
    if (f.pixel_rep == 1 && f.bits_allocated == 16 && raw < -0x8000) return raw + 0x10000;
    return raw;
  };
  if (get_int(ds, DCM_PixelPaddingValue, value)) f.has_padding = true, f.padding = as_stored(value);
  if (get_int(ds, DCM_PixelPaddingRangeLimit, value)) f.has_padding_limit = true, f.padding_limit = as_stored(value);
  const std::string image_type = get_string(ds, DCM_ImageType);
  f.localizer = image_type.find("LOCALIZER") != std::string::npos;
  if (std::string bad = read_modality_lut(ds, f); !bad.empty()) return fail(f, FileKind::broken, std::move(bad));
  return true;
}

/// The frame count into `frames`: classic images have one; enhanced ones describe each in
/// functional groups. The count must be what the file holds: every declared frame in the pixel
/// data (and described, when per-frame groups are there), so that a damaged count cannot make
/// us loop or allocate. False (and `f` broken) otherwise.
bool read_frame_count(DcmDataset* ds, DcmSequenceOfItems* per_frame_seq, FileInfo& f, long& frames) {
  long value = 0;
  frames = 1;
  if (ds->tagExists(DCM_NumberOfFrames)) {
    if (!get_int(ds, DCM_NumberOfFrames, value) || value < 1)
      return fail(f, FileKind::broken,
                  fmt::format("its NumberOfFrames (0028,0008) '{}' is not a positive count",
                              printable(trim(get_string(ds, DCM_NumberOfFrames)))));
    frames = value;
  }
  if (std::string bad = check_frame_count(ds, f, frames, per_frame_seq); !bad.empty())
    return fail(f, FileKind::broken, std::move(bad));
  return true;
}

/// Frame `fr`'s geometry (position, orientation, pixel spacing, thickness) and rescale, from its
/// per-frame functional groups, else the shared ones, else the top level of `ds`.
FrameInfo read_frame(DcmDataset* ds, DcmItem* per_frame, DcmItem* shared, long fr, long base_instance,
                     std::size_t file_index) {
  FrameInfo info;
  info.file = file_index;
  info.frame = int(fr);
  info.instance = base_instance * 100000 + fr;
  double v[6];
  if (get_doubles(find_functional(ds, per_frame, shared, DCM_PlanePositionSequence, DCM_ImagePositionPatient),
                  DCM_ImagePositionPatient, v, 3)) {
    info.has_position = true;
    info.position = {v[0], v[1], v[2]};
  }
  if (get_doubles(find_functional(ds, per_frame, shared, DCM_PlaneOrientationSequence, DCM_ImageOrientationPatient),
                  DCM_ImageOrientationPatient, v, 6)) {
    const Eigen::Vector3d r(v[0], v[1], v[2]), c(v[3], v[4], v[5]);
    if (r.norm() > 0.5 && c.norm() > 0.5 && std::abs(r.normalized().dot(c.normalized())) < 1e-3) {
      info.has_orientation = true;
      info.row = r.normalized();
      info.col = c.normalized();
    }
  }
  if (get_doubles(find_functional(ds, per_frame, shared, DCM_PixelMeasuresSequence, DCM_PixelSpacing), DCM_PixelSpacing,
                  v, 2) &&
      v[0] > 0 && v[1] > 0) {
    info.has_spacing = true;
    info.row_spacing = v[0];
    info.col_spacing = v[1];
  }
  if (get_doubles(find_functional(ds, per_frame, shared, DCM_PixelMeasuresSequence, DCM_SliceThickness),
                  DCM_SliceThickness, v, 1) &&
      v[0] > 0 && std::isfinite(v[0]))
    info.slice_thickness = v[0];
  if (get_doubles(ds, DCM_SpacingBetweenSlices, v, 1) && v[0] > 0)
    info.thickness = v[0];
  else if (get_doubles(find_functional(ds, per_frame, shared, DCM_PixelMeasuresSequence, DCM_SliceThickness),
                       DCM_SliceThickness, v, 1) &&
           v[0] > 0)
    info.thickness = v[0];
  DcmItem* rescale = find_functional(ds, per_frame, shared, DCM_PixelValueTransformationSequence, DCM_RescaleSlope);
  if (get_doubles(rescale, DCM_RescaleSlope, v, 1) && get_doubles(rescale, DCM_RescaleIntercept, v + 1, 1)) {
    info.has_rescale = true;
    info.slope = v[0];
    info.intercept = v[1];
  }
  return info;
}

}  // namespace

FileInfo read_header(const fs::path& path, bool explicit_input, std::size_t file_index) {
  FileInfo f;
  f.path = path;
  f.explicit_input = explicit_input;
  const bool magic = has_dicm_magic(path);
  DcmFileFormat ff;
  const OFCondition status = ff.loadFile(path.c_str(), EXS_Unknown, EGL_noChange, kHeaderReadLimit, ERM_autoDetect);
  DcmDataset* ds = ff.getDataset();
  if (!check_declared_lengths(ds, path, magic, f) || !read_identity(ds, status, magic, f)) return f;
  read_transfer_syntax(ff, ds, f);
  if (!read_image_layout(ds, f)) return f;
  DcmItem* shared = nullptr;
  ds->findAndGetSequenceItem(DCM_SharedFunctionalGroupsSequence, shared, 0);
  DcmSequenceOfItems* per_frame_seq = nullptr;
  ds->findAndGetSequence(DCM_PerFrameFunctionalGroupsSequence, per_frame_seq);
  long frames = 1;
  if (!read_frame_count(ds, per_frame_seq, f, frames)) return f;
  long value = 0;
  const long base_instance = get_int(ds, DCM_InstanceNumber, value) ? value : 0;
  for (long fr = 0; fr < frames; ++fr) {
    DcmItem* per_frame =
        per_frame_seq && fr < long(per_frame_seq->card()) ? per_frame_seq->getItem(unsigned(fr)) : nullptr;
    f.frames.push_back(read_frame(ds, per_frame, shared, fr, base_instance, file_index));
  }
  return f;
}

std::vector<FileInfo> read_headers(const std::vector<std::pair<fs::path, bool>>& listed) {
  std::vector<FileInfo> files;
  files.reserve(listed.size());
  Progress progress("Reading DICOM headers", listed.size() >= kProgressFrom);
  for (std::size_t i = 0; i < listed.size(); ++i) {
    files.push_back(read_header(listed[i].first, listed[i].second, i));
    progress.update(double(i + 1) / double(listed.size()));
  }
  progress.done();
  return files;
}

}  // namespace vx::dicom
