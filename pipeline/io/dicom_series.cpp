// Reading a DICOM CT series into a float HU volume (DCMTK).
//
// Two passes keep memory at about the size of the volume: headers first (each file loaded
// with a read-length limit, so pixel data stays on disk), then the pixels of the chosen
// series frame by frame straight into the float volume.

#include "io/dicom_series.h"

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

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <map>
#include <new>
#include <numbers>
#include <numeric>
#include <optional>
#include <set>

#include "base/error.h"
#include "io/dicom_common.h"
#include "util/log.h"
#include "util/progress.h"
#include "util/text.h"

namespace vx {
namespace {
namespace fs = std::filesystem;

// values longer than this stay on disk during the header pass (pixel data, big private blobs)
constexpr Uint32 kHeaderReadLimit = 4096;
// progress is shown from this many files / frames on
constexpr std::size_t kProgressFrom = 64;

/// One frame (a 2D image) of a file: a classic file has one, an enhanced one many.
struct FrameInfo {
  std::size_t file{0};  ///< index into the file list
  int frame{0};         ///< 0-based frame number in the file
  bool has_position{false}, has_orientation{false}, has_spacing{false};
  Eigen::Vector3d position{0, 0, 0};  ///< ImagePositionPatient: centre of the first pixel, LPS mm
  Eigen::Vector3d row{1, 0, 0};       ///< direction of increasing column index (along a row)
  Eigen::Vector3d col{0, 1, 0};       ///< direction of increasing row index (down a column)
  double row_spacing{1.0};            ///< PixelSpacing[0]: between rows, mm
  double col_spacing{1.0};            ///< PixelSpacing[1]: between columns, mm
  double thickness{0.0};              ///< SliceThickness or SpacingBetweenSlices, mm (fallback only)
  double slice_thickness{0.0};        ///< SliceThickness, mm (0: absent): a single slice's depth
  double slope{1.0}, intercept{0.0};  ///< rescale to HU
  bool has_rescale{false};
  long instance{0};  ///< InstanceNumber / frame number, for ordering without geometry
  double normal_position{0.0};  ///< position projected on the slice normal, mm
};

enum class FileKind { image, not_dicom, non_image, broken };

/// What the header pass learnt about one file.
struct FileInfo {
  fs::path path;
  bool explicit_input{false};  ///< named on the command line (not found in a folder)
  FileKind kind{FileKind::not_dicom};
  std::string problem;  ///< why it is broken / not DICOM
  std::string series_uid, sop_class, sop_instance, modality, description;
  std::string xfer_uid, xfer_name;
  bool xfer_decodable{true};
  int rows{0}, cols{0}, bits_allocated{0}, bits_stored{0}, high_bit{0}, pixel_rep{0}, samples{1};
  std::string photometric;
  bool has_padding{false}, has_padding_limit{false};
  long padding{0}, padding_limit{0};  ///< raw stored values (sign applied)
  bool localizer{false};
  bool is_ct{false};
  /// Modality LUT Sequence (0028,3000), when present: stored value v -> lut[clamp(v - lut_first)]
  std::vector<double> lut;
  long lut_first{0};
  std::vector<FrameInfo> frames;
};

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

/// `s` fit for a terminal: control characters (escape sequences from a hostile file) become '?'.
std::string printable(std::string s) {
  for (char& c : s)
    if ((static_cast<unsigned char>(c) < 0x20 && c != '\t') || c == 0x7f) c = '?';
  return s;
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
  if (bits != 8 && bits != 16)
    return fmt::format("its Modality LUT has {} bits per entry (8 or 16 are defined)", bits);
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
    return "";
  }
  const double frame_bytes = double(f.rows) * double(f.cols) * double(std::max(f.samples, 1)) *
                             double(std::max(f.bits_allocated, 1)) / 8.0;
  const double held = double(element->getLengthField());
  if (double(frames) * frame_bytes > held)
    return fmt::format("it declares {} frame{} of {} x {} pixels ({:.0f} bytes) but its pixel data holds {:.0f} bytes "
                       "(the file is damaged or cut short)",
                       frames, frames == 1 ? "" : "s", f.cols, f.rows, double(frames) * frame_bytes, held);
  return "";
}

/// Everything about a file except its pixel values.
FileInfo read_header(const fs::path& path, bool explicit_input, std::size_t file_index) {
  FileInfo f;
  f.path = path;
  f.explicit_input = explicit_input;
  const bool magic = dicom::has_dicm_magic(path);
  DcmFileFormat ff;
  const OFCondition status = ff.loadFile(path.c_str(), EXS_Unknown, EGL_noChange, kHeaderReadLimit, ERM_autoDetect);
  DcmDataset* ds = ff.getDataset();
  if (ds) {
    // a value longer than the whole file is a damaged length: reading it (values beyond the
    // read limit load on first access) would allocate that much, up to 4 GB (found by fuzzing)
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
      if (o && o->isLeaf() && declared != DCM_UndefinedLength && std::uintmax_t(declared) > file_bytes) {
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
        const std::string what = fmt::format("element ({:04x},{:04x}) declares {} bytes, more than the whole file "
                                             "({} bytes)",
                                             o->getGTag(), o->getETag(), declared, file_bytes);
        if (magic || uid_elements) {
          f.kind = FileKind::broken;
          f.problem = "it is truncated or damaged: " + what;
        } else {
          f.kind = FileKind::not_dicom;
          f.problem = "it is not a DICOM file (no 'DICM' marker, and read as a DICOM data set its " + what + ")";
        }
        return f;
      }
    }
  }
  f.sop_class = trim(get_string(ds, DCM_SOPClassUID));
  f.series_uid = printable(trim(get_string(ds, DCM_SeriesInstanceUID)));
  const bool looks_dicom = magic || !f.sop_class.empty() || !f.series_uid.empty();
  if (status.bad()) {
    f.kind = looks_dicom ? FileKind::broken : FileKind::not_dicom;
    f.problem = looks_dicom ? fmt::format("it is truncated or corrupt (DCMTK: {})", status.text())
                            : "it is not a DICOM file (no 'DICM' marker and no DICOM data set)";
    return f;
  }
  if (!looks_dicom) {
    f.kind = FileKind::not_dicom;
    f.problem = "it is not a DICOM file (no 'DICM' marker and no SOP Class UID)";
    return f;
  }
  f.sop_instance = trim(get_string(ds, DCM_SOPInstanceUID));
  f.modality = printable(trim(get_string(ds, DCM_Modality)));
  f.description = get_text_utf8(ds, DCM_SeriesDescription);
  f.is_ct = is_ct_sop_class(f.sop_class);

  // transfer syntax: can DCMTK decode it here?
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

  // is it an image at all?
  long value = 0;
  const bool has_rows = ds->tagExists(DCM_Rows);
  if (!ds->tagExists(DCM_PixelData)) {
    if (has_rows || f.is_ct) {
      f.kind = FileKind::broken;
      f.problem = "it has no pixel data element (7FE0,0010)";
    } else {
      f.kind = FileKind::non_image;  // DICOMDIR, structured report, presentation state, ...
    }
    return f;
  }
  f.kind = FileKind::image;
  auto require = [&](const DcmTagKey& tag, const char* name, int& out) {
    if (!get_int(ds, tag, value)) {
      f.kind = FileKind::broken;
      f.problem = fmt::format("it has no {} element", name);
      return false;
    }
    out = int(value);
    return true;
  };
  if (!require(DCM_Rows, "Rows (0028,0010)", f.rows) || !require(DCM_Columns, "Columns (0028,0011)", f.cols) ||
      !require(DCM_BitsAllocated, "BitsAllocated (0028,0100)", f.bits_allocated))
    return f;
  f.bits_stored = get_int(ds, DCM_BitsStored, value) ? int(value) : f.bits_allocated;
  f.high_bit = get_int(ds, DCM_HighBit, value) ? int(value) : f.bits_stored - 1;
  f.pixel_rep = get_int(ds, DCM_PixelRepresentation, value) ? int(value) : 0;
  f.samples = get_int(ds, DCM_SamplesPerPixel, value) ? int(value) : 1;
  f.photometric = trim(get_string(ds, DCM_PhotometricInterpretation));
  if (f.rows <= 0 || f.cols <= 0) {
    f.kind = FileKind::broken;
    f.problem = fmt::format("it has an empty image ({} rows x {} columns)", f.rows, f.cols);
    return f;
  }
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

  if (const std::string bad = read_modality_lut(ds, f); !bad.empty()) {
    f.kind = FileKind::broken;
    f.problem = bad;
    return f;
  }

  // frames: classic images have one; enhanced ones describe each in functional groups. The
  // count must be what the file holds: every declared frame in the pixel data (and described,
  // when per-frame groups are there), so that a damaged count cannot make us loop or allocate
  long frames = 1;
  if (ds->tagExists(DCM_NumberOfFrames)) {
    if (!get_int(ds, DCM_NumberOfFrames, value) || value < 1) {
      f.kind = FileKind::broken;
      f.problem = fmt::format("its NumberOfFrames (0028,0008) '{}' is not a positive count",
                              printable(trim(get_string(ds, DCM_NumberOfFrames))));
      return f;
    }
    frames = value;
  }
  DcmItem* shared = nullptr;
  ds->findAndGetSequenceItem(DCM_SharedFunctionalGroupsSequence, shared, 0);
  DcmSequenceOfItems* per_frame_seq = nullptr;
  ds->findAndGetSequence(DCM_PerFrameFunctionalGroupsSequence, per_frame_seq);
  if (const std::string bad = check_frame_count(ds, f, frames, per_frame_seq); !bad.empty()) {
    f.kind = FileKind::broken;
    f.problem = bad;
    return f;
  }
  long base_instance = get_int(ds, DCM_InstanceNumber, value) ? value : 0;
  for (long fr = 0; fr < frames; ++fr) {
    FrameInfo info;
    info.file = file_index;
    info.frame = int(fr);
    info.instance = base_instance * 100000 + fr;
    DcmItem* per_frame = per_frame_seq && fr < long(per_frame_seq->card()) ? per_frame_seq->getItem(unsigned(fr)) : nullptr;
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
    if (get_doubles(find_functional(ds, per_frame, shared, DCM_PixelMeasuresSequence, DCM_PixelSpacing),
                    DCM_PixelSpacing, v, 2) && v[0] > 0 && v[1] > 0) {
      info.has_spacing = true;
      info.row_spacing = v[0];
      info.col_spacing = v[1];
    }
    if (get_doubles(find_functional(ds, per_frame, shared, DCM_PixelMeasuresSequence, DCM_SliceThickness),
                    DCM_SliceThickness, v, 1) && v[0] > 0 && std::isfinite(v[0]))
      info.slice_thickness = v[0];
    if (get_doubles(ds, DCM_SpacingBetweenSlices, v, 1) && v[0] > 0) info.thickness = v[0];
    else if (get_doubles(find_functional(ds, per_frame, shared, DCM_PixelMeasuresSequence, DCM_SliceThickness),
                         DCM_SliceThickness, v, 1) && v[0] > 0)
      info.thickness = v[0];
    DcmItem* rescale = find_functional(ds, per_frame, shared, DCM_PixelValueTransformationSequence, DCM_RescaleSlope);
    if (get_doubles(rescale, DCM_RescaleSlope, v, 1) && get_doubles(rescale, DCM_RescaleIntercept, v + 1, 1)) {
      info.has_rescale = true;
      info.slope = v[0];
      info.intercept = v[1];
    }
    f.frames.push_back(info);
  }
  return f;
}

/// Files named by the inputs, with whether each was named itself: folders are searched
/// (recursively unless `recursive` is false), their files sorted by path.
std::vector<std::pair<fs::path, bool>> collect_files(const std::vector<fs::path>& inputs, bool recursive = true) {
  if (inputs.empty()) throw Error("DICOM: no input given (give a folder holding a series, or its files)");
  std::vector<std::pair<fs::path, bool>> files;
  for (const fs::path& input : inputs) {
    std::error_code ec;
    if (fs::is_directory(input, ec)) {
      std::vector<fs::path> found;
      fs::recursive_directory_iterator it(input, fs::directory_options::skip_permission_denied, ec);
      if (ec) throw Error(fmt::format("DICOM: cannot list folder {}: {}", quoted(input), ec.message()));
      for (; it != fs::recursive_directory_iterator(); it.increment(ec)) {
        if (ec) throw Error(fmt::format("DICOM: cannot list folder {}: {}", quoted(input), ec.message()));
        if (!recursive) it.disable_recursion_pending();
        std::error_code ec2;
        if (it->is_regular_file(ec2)) found.push_back(it->path());
      }
      if (found.empty())
        throw Error(fmt::format("DICOM: folder {} holds no files (point to the folder that holds the series' .dcm files)",
                                quoted(input)));
      std::sort(found.begin(), found.end());
      for (auto& p : found) files.emplace_back(std::move(p), false);
    } else if (fs::is_regular_file(input, ec)) {
      files.emplace_back(input, true);
    } else if (fs::exists(input, ec)) {
      throw Error(fmt::format("DICOM: {} is neither a file nor a folder", quoted(input)));
    } else {
      throw Error(fmt::format("DICOM: {} does not exist (check the path)", quoted(input)));
    }
  }
  return files;
}

/// A series found in the inputs.
struct SeriesInfo {
  std::string uid;
  std::vector<std::size_t> files;  ///< image files (localizers excluded)
  std::size_t frames{0};
  std::size_t localizers{0};
  std::string modality, description;
  bool is_ct{false};
  [[nodiscard]] std::string label() const {
    return fmt::format("{} ({}, {} image{}{})", uid, modality.empty() ? "no modality" : modality, frames,
                       frames == 1 ? "" : "s", description.empty() ? "" : ", '" + description + "'");
  }
};

std::string list_series(const std::vector<const SeriesInfo*>& series) {
  std::string s;
  for (const SeriesInfo* si : series) s += "\n  " + si->label();
  return s;
}

double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  const std::size_t n = v.size();
  return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

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
      out[p] = dicom::kAirHu;
    } else if (!f.lut.empty()) {
      const std::int64_t e = std::clamp<std::int64_t>(v - f.lut_first, 0, std::int64_t(f.lut.size()) - 1);
      out[p] = float(f.lut[std::size_t(e)]);
    } else {
      out[p] = float(double(v) * fr.slope + fr.intercept);
    }
  }
}

/// Chooses the series to read and says which others were found.
const SeriesInfo& choose_series(const std::map<std::string, SeriesInfo>& all, const ReadOptions& options,
                                const std::string& where) {
  std::vector<const SeriesInfo*> series;
  for (const auto& [uid, s] : all)
    if (s.frames > 0) series.push_back(&s);
  std::sort(series.begin(), series.end(), [](const SeriesInfo* a, const SeriesInfo* b) {
    return a->frames != b->frames ? a->frames > b->frames : a->uid < b->uid;
  });
  if (series.empty()) {
    std::size_t localizers = 0;
    for (const auto& [uid, s] : all) localizers += s.localizers;
    if (localizers > 0)
      throw Error(fmt::format("DICOM: {} holds only localizer (scout) images ({}), no volume to read", where, localizers));
    throw Error(fmt::format("DICOM: {} holds no DICOM images", where));
  }
  const SeriesInfo* chosen = nullptr;
  if (!options.series_uid.empty()) {
    for (const SeriesInfo* s : series)
      if (s->uid == options.series_uid) chosen = s;
    if (!chosen)
      throw Error(fmt::format("DICOM: series {} is not in {}; the series found are:{}\n(pass one of these UIDs to --series)",
                              options.series_uid, where, list_series(series)));
    if (!chosen->is_ct && !options.any_modality)
      throw Error(fmt::format("DICOM: series {} is not CT ({}), so its values are not Hounsfield units; "
                              "pass --modality any (in a scene: \"any_modality\": true) to read it anyway",
                              chosen->uid, chosen->modality.empty() ? "unknown modality" : chosen->modality));
  } else {
    for (const SeriesInfo* s : series)
      if (s->is_ct || options.any_modality) {
        chosen = s;
        break;
      }
    if (!chosen)
      throw Error(fmt::format("DICOM: {} holds no CT series, only:{}\nThese values are not Hounsfield units; pass "
                              "--modality any (in a scene: \"any_modality\": true) to read one anyway (the largest is taken, "
                              "or the one given with --series)",
                              where, list_series(series)));
  }
  std::vector<const SeriesInfo*> others;
  for (const SeriesInfo* s : series)
    if (s != chosen) others.push_back(s);
  if (!others.empty())
    log::info("DICOM: reading series {}\nDICOM: also found (choose with --series UID):{}", chosen->label(),
              list_series(others));
  if (!chosen->is_ct)
    log::warn("DICOM: series {} is {}, not CT: its values are not Hounsfield units, choose the threshold accordingly",
              chosen->uid, chosen->modality.empty() ? "of unknown modality" : chosen->modality);
  return *chosen;
}

/// Where the sorted frames sit: the grid and, per slice, the in-plane shift a gantry tilt causes.
struct SliceLayout {
  GridGeometry geometry;           ///< output grid (orthogonal)
  std::vector<Eigen::Vector2d> shift;  ///< per slice: input pixel (i',j') = output (i,j) + offset - shift
  Eigen::Vector2i offset{0, 0};
  bool tilted{false};
};

std::string frame_name(const std::vector<FileInfo>& files, const FrameInfo& fr) {
  const FileInfo& f = files[fr.file];
  return f.frames.size() > 1 ? fmt::format("frame {} of {}", fr.frame + 1, quoted(f.path)) : quoted(f.path);
}

/// Sorts frames along the slice normal and checks duplicates, gaps, spacing and tilt.
SliceLayout lay_out_slices(std::vector<FileInfo>& files, std::vector<FrameInfo>& frames, const SeriesInfo& series,
                           const ReadOptions& options) {
  const FrameInfo first = frames.front();  // a copy: frames get sorted below
  const FileInfo& ff = files[first.file];
  SliceLayout layout;
  // every frame must share the image size, pixel layout, orientation and pixel spacing
  for (const FrameInfo& fr : frames) {
    const FileInfo& f = files[fr.file];
    if (f.rows != ff.rows || f.cols != ff.cols)
      throw Error(fmt::format("DICOM: series {} mixes image sizes: {} is {} x {} (columns x rows) but {} is {} x {}; "
                              "the slices of a volume must all have the same size (remove the odd files or choose "
                              "another series with --series)",
                              series.uid, frame_name(files, first), ff.cols, ff.rows, frame_name(files, fr), f.cols, f.rows));
    if (f.samples != 1)
      throw Error(fmt::format("DICOM: {} is a colour image (SamplesPerPixel {}, {}); only greyscale CT-like images "
                              "can become a volume", frame_name(files, fr), f.samples, f.photometric));
    if (f.photometric != "MONOCHROME1" && f.photometric != "MONOCHROME2" && !f.photometric.empty())
      throw Error(fmt::format("DICOM: {} has photometric interpretation {}; only MONOCHROME1/2 images can become a volume",
                              frame_name(files, fr), f.photometric));
    if (f.bits_allocated != 8 && f.bits_allocated != 16 && f.bits_allocated != 32)
      throw Error(fmt::format("DICOM: {} has {} bits allocated per pixel; only 8, 16 and 32 are supported",
                              frame_name(files, fr), f.bits_allocated));
    if (f.bits_stored < 1 || f.bits_stored > f.bits_allocated || f.high_bit >= f.bits_allocated)
      throw Error(fmt::format("DICOM: {} has inconsistent BitsStored {} / HighBit {} for BitsAllocated {}",
                              frame_name(files, fr), f.bits_stored, f.high_bit, f.bits_allocated));
  }
  const bool have_geometry = std::all_of(frames.begin(), frames.end(), [](const FrameInfo& fr) {
    return fr.has_position && fr.has_orientation;
  });
  if (!have_geometry) {
    const auto missing = std::find_if(frames.begin(), frames.end(), [](const FrameInfo& fr) {
      return !fr.has_position || !fr.has_orientation;
    });
    if (!options.any_modality || series.is_ct)
      throw Error(fmt::format("DICOM: {} has no usable ImagePositionPatient / ImageOrientationPatient, so the slices "
                              "cannot be placed in patient space (the series is incomplete; re-export it)",
                              frame_name(files, *missing)));
    log::warn("DICOM: {} has no patient position/orientation; slices are ordered by InstanceNumber and placed on an "
              "axis-aligned grid",
              frame_name(files, *missing));
    std::sort(frames.begin(), frames.end(), [&](const FrameInfo& a, const FrameInfo& b) {
      return a.instance != b.instance ? a.instance < b.instance : files[a.file].path < files[b.file].path;
    });
    const double dz = first.thickness > 0 ? first.thickness : 1.0;
    for (std::size_t k = 0; k < frames.size(); ++k) {
      frames[k].position = Eigen::Vector3d(0, 0, dz * double(k));
      frames[k].row = Eigen::Vector3d::UnitX();
      frames[k].col = Eigen::Vector3d::UnitY();
    }
  }
  const Eigen::Vector3d row = frames.front().row, col = frames.front().col;
  const double row_spacing = frames.front().row_spacing, col_spacing = frames.front().col_spacing;
  for (const FrameInfo& fr : frames) {
    if ((fr.row - row).norm() > 1e-4 || (fr.col - col).norm() > 1e-4)
      throw Error(fmt::format("DICOM: series {} mixes slice orientations ({} differs from {}); a volume needs parallel "
                              "slices (choose another series with --series, or split the series)",
                              series.uid, frame_name(files, fr), frame_name(files, frames.front())));
    if (std::abs(fr.row_spacing - row_spacing) > 1e-4 * row_spacing ||
        std::abs(fr.col_spacing - col_spacing) > 1e-4 * col_spacing)
      throw Error(fmt::format("DICOM: series {} mixes pixel spacings: {} has {} x {} mm but {} has {} x {} mm",
                              series.uid, frame_name(files, frames.front()), row_spacing, col_spacing,
                              frame_name(files, fr), fr.row_spacing, fr.col_spacing));
  }
  if (!frames.front().has_spacing)
    log::warn("DICOM: no PixelSpacing in {}; assuming 1 mm pixels", frame_name(files, frames.front()));
  if (frames.size() == 1)
    log::info("DICOM: series {} has a single slice ({}): a one-slice volume, which convert makes a 2D model",
              series.uid, frame_name(files, frames.front()));
  const Eigen::Vector3d normal = row.cross(col).normalized();

  // sort by position along the normal (not InstanceNumber)
  for (FrameInfo& fr : frames) fr.normal_position = fr.position.dot(normal);
  std::stable_sort(frames.begin(), frames.end(), [](const FrameInfo& a, const FrameInfo& b) {
    return a.normal_position < b.normal_position;
  });

  // duplicates: the same image twice is dropped, two images at one place are refused
  constexpr double kSamePlaceMm = 1e-3;
  std::vector<FrameInfo> unique;
  std::size_t dropped = 0;
  for (const FrameInfo& fr : frames) {
    if (!unique.empty() && fr.normal_position - unique.back().normal_position < kSamePlaceMm) {
      const FileInfo& a = files[unique.back().file];
      const FileInfo& b = files[fr.file];
      if (!a.sop_instance.empty() && a.sop_instance == b.sop_instance && unique.back().frame == fr.frame) {
        ++dropped;
        continue;
      }
      throw Error(fmt::format("DICOM: series {} has two different slices at the same position ({:.3f} mm along the "
                              "slice normal): {} and {}. The series may hold several phases or echoes; remove the "
                              "extra files or choose one series with --series",
                              series.uid, fr.normal_position, frame_name(files, unique.back()), frame_name(files, fr)));
    }
    unique.push_back(fr);
  }
  if (dropped)
    log::info("DICOM: ignored {} duplicate cop{} of images already read", dropped, dropped == 1 ? "y" : "ies");
  frames = std::move(unique);

  // spacing: median difference, then every gap checked against it. One slice: its depth is the
  // slice thickness (SliceThickness, else SpacingBetweenSlices, else 1 mm), the thickness of the
  // 2D model's plane-stress slab (docs/model.md section 12)
  std::vector<double> gaps;
  for (std::size_t k = 1; k < frames.size(); ++k) gaps.push_back(frames[k].normal_position - frames[k - 1].normal_position);
  double dz = 0;
  if (frames.size() == 1) {
    const FrameInfo& only = frames.front();
    dz = only.slice_thickness > 0 ? only.slice_thickness : only.thickness;
    if (!(dz > 0)) {
      dz = 1.0;
      log::warn("DICOM: {} gives no SliceThickness (0018,0050) or SpacingBetweenSlices (0018,0088); assuming a 1 mm "
                "thick slice (the 2D model's forces scale with it)",
                frame_name(files, only));
    }
  } else {
    dz = median(gaps);
  }
  const double tolerance = std::max(0.01, 0.05 * dz);
  for (std::size_t k = 1; k < frames.size(); ++k) {
    const double gap = gaps[k - 1];
    if (std::abs(gap - dz) <= tolerance) continue;
    const double ratio = gap / dz;
    const long whole = std::lround(ratio);
    if (whole >= 2 && std::abs(gap - double(whole) * dz) <= tolerance)
      throw Error(fmt::format("DICOM: series {} misses {} slice{} between {} and {} (gap {:.3f} mm, slice spacing "
                              "{:.3f} mm); the series is incomplete, re-export it",
                              series.uid, whole - 1, whole - 1 == 1 ? "" : "s", frame_name(files, frames[k - 1]),
                              frame_name(files, frames[k]), gap, dz));
    throw Error(fmt::format("DICOM: series {} has non-uniform slice spacing: {:.3f} mm between {} and {}, but "
                            "{:.3f} mm typically; a volume needs evenly spaced slices (resample the series first)",
                            series.uid, gap, frame_name(files, frames[k - 1]), frame_name(files, frames[k]), dz));
  }

  // gantry tilt: slice origins drift within the slice plane; shear each slice back
  layout.shift.resize(frames.size(), Eigen::Vector2d::Zero());
  double max_drift = 0.0;
  Eigen::Vector2d lo(0, 0), hi(0, 0);
  for (std::size_t k = 0; k < frames.size(); ++k) {
    const Eigen::Vector3d d = frames[k].position - frames.front().position;
    const Eigen::Vector3d in_plane = d - d.dot(normal) * normal;
    max_drift = std::max(max_drift, in_plane.norm());
    layout.shift[k] = Eigen::Vector2d(in_plane.dot(row) / col_spacing, in_plane.dot(col) / row_spacing);
    lo = lo.cwiseMin(layout.shift[k]);
    hi = hi.cwiseMax(layout.shift[k]);
  }
  // drifts under 5% of a pixel are rounding in the positions, not a tilt worth resampling
  layout.tilted = max_drift > 0.05 * std::min(row_spacing, col_spacing);
  Eigen::Vector3i dims(ff.cols, ff.rows, int(frames.size()));
  if (layout.tilted) {
    // the output grid covers every sheared slice
    layout.offset = Eigen::Vector2i(int(std::floor(lo.x() + 1e-6)), int(std::floor(lo.y() + 1e-6)));
    const Eigen::Vector2i top(int(std::ceil(hi.x() - 1e-6)), int(std::ceil(hi.y() - 1e-6)));
    dims.x() = ff.cols + top.x() - layout.offset.x();
    dims.y() = ff.rows + top.y() - layout.offset.y();
    const double span = frames.back().normal_position - frames.front().normal_position;
    const double angle = std::atan2(
        (frames.back().position - frames.front().position - span * normal).norm(), span) * 180.0 / std::numbers::pi;
    log::warn("DICOM: series {} is tilted by {:.2f} degrees (gantry tilt); resampling it onto an orthogonal grid of "
              "{} x {} x {} voxels (samples outside the scan become air)",
              series.uid, angle, dims.x(), dims.y(), dims.z());
  } else {
    for (auto& s : layout.shift) s.setZero();
  }
  GridGeometry& g = layout.geometry;
  g.dims = dims;
  g.spacing_mm = Eigen::Vector3d(col_spacing, row_spacing, dz);
  g.direction.col(0) = row;
  g.direction.col(1) = col;
  g.direction.col(2) = normal;
  g.origin_mm = frames.front().position + row * (layout.offset.x() * col_spacing) + col * (layout.offset.y() * row_spacing);
  return layout;
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
        v = dicom::kAirHu;
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

/// The inputs to read: one single-frame file stands for its series, which is then read from
/// the file's folder (that folder only, not its subfolders: `recursive` false) with the series
/// UID set from the file; `where` names the inputs in messages.
std::vector<fs::path> resolve_single_file(const std::vector<fs::path>& inputs_in, ReadOptions& opts, std::string& where,
                                          bool& recursive) {
  std::vector<fs::path> inputs = inputs_in;
  if (inputs.size() == 1) {
    std::error_code ec;
    if (fs::is_regular_file(inputs.front(), ec)) {
      FileInfo one = read_header(inputs.front(), true, 0);
      if (one.kind != FileKind::image) {
        throw Error(fmt::format("DICOM: cannot read {}: {}", quoted(one.path), one.problem.empty() ? "it holds no image" : one.problem));
      }
      if (one.frames.size() == 1 && !one.series_uid.empty()) {
        const fs::path folder = inputs.front().has_parent_path() ? inputs.front().parent_path() : fs::path(".");
        if (opts.series_uid.empty()) opts.series_uid = one.series_uid;
        log::info("DICOM: {} is one slice; reading its series from folder '{}'", inputs.front().string(),
                  folder.string());
        inputs = {folder};
        where = quoted(folder);
        recursive = false;
      }
    }
  }
  return inputs;
}

/// The header pass: everything about each file but its pixels.
std::vector<FileInfo> read_headers(const std::vector<std::pair<fs::path, bool>>& listed) {
  std::vector<FileInfo> files;
  files.reserve(listed.size());
  {
    Progress progress("Reading DICOM headers", listed.size() >= kProgressFrom);
    for (std::size_t i = 0; i < listed.size(); ++i) {
      files.push_back(read_header(listed[i].first, listed[i].second, i));
      progress.update(double(i + 1) / double(listed.size()));
    }
    progress.done();
  }

  return files;
}

/// Names the files of a list in a warning, the first 20 of them.
std::string name_files(const std::vector<const FileInfo*>& list) {
  std::string out;
  for (std::size_t i = 0; i < list.size() && i < 20; ++i)
    out += fmt::format("\n  {}: {}", list[i]->path.string(), list[i]->problem);
  if (list.size() > 20) out += fmt::format("\n  ... and {} more", list.size() - 20);
  return out;
}

/// Problems that are fatal whatever the series (named files that are not DICOM or cannot be
/// read), and the files skipped: not DICOM, DICOM without images, and unreadable files whose
/// series is unknown (a truncated RT plan beside the CT series, say), each named in a warning.
/// A missing slice of the series read is still caught by the spacing checks.
std::vector<const FileInfo*> check_files(const std::vector<FileInfo>& files, const std::string& where) {
  std::vector<const FileInfo*> not_dicom, unknown_broken;
  std::size_t non_image = 0;
  for (const FileInfo& f : files) {
    if ((f.kind == FileKind::not_dicom || (f.kind == FileKind::broken && f.series_uid.empty())) && f.explicit_input)
      throw Error(fmt::format("DICOM: cannot read {}: {}", quoted(f.path), f.problem));
    if (f.kind == FileKind::not_dicom) not_dicom.push_back(&f);
    if (f.kind == FileKind::non_image) ++non_image;
    if (f.kind == FileKind::broken && f.series_uid.empty()) unknown_broken.push_back(&f);
  }
  if (not_dicom.size() == files.size())
    throw Error(fmt::format("DICOM: {} holds {} file{}, none of them DICOM (e.g. {}: {}); point to the folder "
                            "that holds the series' .dcm files",
                            where, files.size(), files.size() == 1 ? "" : "s", quoted(not_dicom.front()->path),
                            not_dicom.front()->problem));
  if (!not_dicom.empty())
    log::info("DICOM: skipped {} file{} that {} not DICOM:{}", not_dicom.size(), not_dicom.size() == 1 ? "" : "s",
              not_dicom.size() == 1 ? "is" : "are", name_files(not_dicom));
  if (!unknown_broken.empty())
    log::warn("DICOM: skipped {} unreadable DICOM file{} whose series cannot be told (if one belongs to the series "
              "read, the slice spacing check reports the gap it leaves):{}",
              unknown_broken.size(), unknown_broken.size() == 1 ? "" : "s", name_files(unknown_broken));
  if (non_image)
    log::info("DICOM: skipped {} DICOM file{} without images (reports, DICOMDIR, ...)", non_image,
              non_image == 1 ? "" : "s");
  return unknown_broken;
}

/// The series found, by SeriesInstanceUID (localizers counted apart).
std::map<std::string, SeriesInfo> group_series(const std::vector<FileInfo>& files) {
  std::map<std::string, SeriesInfo> all;
  for (std::size_t i = 0; i < files.size(); ++i) {
    const FileInfo& f = files[i];
    if (f.kind != FileKind::image && !(f.kind == FileKind::broken && !f.series_uid.empty())) continue;
    SeriesInfo& s = all[f.series_uid];
    s.uid = f.series_uid.empty() ? "(no SeriesInstanceUID)" : f.series_uid;
    if (f.localizer) {
      s.localizers += f.frames.size();
      continue;
    }
    s.files.push_back(i);
    s.frames += std::max<std::size_t>(f.frames.size(), 1);
    if (s.modality.empty()) s.modality = f.modality;
    if (s.description.empty()) s.description = f.description;
    s.is_ct = s.is_ct || f.is_ct;
  }
  return all;
}

/// The frames of the chosen series, which must be readable throughout.
std::vector<FrameInfo> series_frames(const std::vector<FileInfo>& files, const SeriesInfo& series) {
  std::vector<FrameInfo> frames;
  for (std::size_t i : series.files) {
    const FileInfo& f = files[i];
    if (f.kind == FileKind::broken)
      throw Error(fmt::format("DICOM: cannot read {} of series {}: {}; replace the file (re-export the series) or "
                              "remove it",
                              quoted(f.path), series.uid, f.problem));
    if (!f.xfer_decodable)
      throw Error(fmt::format("DICOM: {} uses transfer syntax '{}' ({}), which voxelastic cannot decode (RLE, JPEG "
                              "incl. lossless, JPEG-LS and JPEG 2000 are supported). Convert the series to an "
                              "uncompressed syntax first, e.g. 'gdcmconv --raw in.dcm out.dcm' (GDCM) or re-export it "
                              "uncompressed from the PACS",
                              quoted(f.path), f.xfer_name, f.xfer_uid));
    if (!f.is_ct && series.is_ct)
      log::warn("DICOM: {} in CT series {} is not a CT image (SOP class {})", f.path.string(), series.uid,
                printable(f.sop_class));
    frames.insert(frames.end(), f.frames.begin(), f.frames.end());
  }
  return frames;
}

/// The volume of the slice layout, filled with air.
Volume allocate_volume(const SliceLayout& layout, const SeriesInfo& series) {
  // the volume
  Volume volume;
  volume.geometry = layout.geometry;
  const std::int64_t voxels = volume.geometry.voxel_count();
  try {
    volume.hu.assign(std::size_t(voxels), dicom::kAirHu);
  } catch (const std::bad_alloc&) {
    throw Error(fmt::format("DICOM: not enough memory for the {} x {} x {} volume of series {} ({:.0f} MB)",
                            volume.geometry.dims.x(), volume.geometry.dims.y(), volume.geometry.dims.z(), series.uid,
                            double(voxels) * 4e-6));
  }

  return volume;
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
    throw Error(fmt::format("DICOM: {} is RLE compressed with {} fragment(s) for {} frame(s) (one per frame after the "
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

/// The pixel pass: file by file (frames of a file in frame order), each frame straight into its
/// slice of `volume`.
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
      throw Error(fmt::format("DICOM: cannot read {} (it changed since its header was read?): {}", quoted(f.path), status.text()));
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
        throw Error(fmt::format("DICOM: cannot decode {}{}: {} (the file may be truncated or its compressed data "
                                "corrupt; transfer syntax {})",
                                quoted(f.path), f.frames.size() > 1 ? fmt::format(" frame {}", frame + 1) : "",
                                status.text(), f.xfer_name));
      frame_to_hu(f, *frame_of_slice[std::size_t(k)], buffer, slice_hu.data());
      place_slice(layout, k, f.rows, f.cols, slice_hu.data(), volume);
      progress.update(double(++done) / double(frames.size()));
    }
  }
  progress.done();
}

}  // namespace

Volume read_dicom_series(const std::vector<fs::path>& inputs, const ReadOptions& options) {
  dicom::init_dcmtk();
  ReadOptions opts = options;
  std::string where = inputs.size() == 1 ? quoted(inputs.front()) : fmt::format("the {} inputs given", inputs.size());
  bool recursive = true;
  const std::vector<fs::path> resolved = resolve_single_file(inputs, opts, where, recursive);
  std::vector<FileInfo> files = read_headers(collect_files(resolved, recursive));
  const std::vector<const FileInfo*> unreadable = check_files(files, where);
  const std::map<std::string, SeriesInfo> all = group_series(files);
  const SeriesInfo& series = choose_series(all, opts, where);
  std::vector<const FileInfo*> broken_elsewhere;
  for (const FileInfo& f : files)
    if (f.kind == FileKind::broken && !f.series_uid.empty() && f.series_uid != series.uid) broken_elsewhere.push_back(&f);
  if (!broken_elsewhere.empty())
    log::warn("DICOM: skipped {} unreadable file{} of other series:{}", broken_elsewhere.size(),
              broken_elsewhere.size() == 1 ? "" : "s", name_files(broken_elsewhere));
  std::vector<FrameInfo> frames = series_frames(files, series);
  const SliceLayout layout = [&] {
    try {
      return lay_out_slices(files, frames, series, opts);
    } catch (const Error& e) {
      // a gap or an uneven spacing may be a slice among the unreadable files skipped: say which
      if (unreadable.empty()) throw;
      throw Error(fmt::format("{}\nDICOM: {} unreadable file{} {} skipped; the missing slice may be among them:{}", e.what(),
                              unreadable.size(), unreadable.size() == 1 ? "" : "s",
                              unreadable.size() == 1 ? "was" : "were", name_files(unreadable)));
    }
  }();
  const bool missing_rescale = std::any_of(frames.begin(), frames.end(), [&](const FrameInfo& fr) {
    return !fr.has_rescale && files[fr.file].lut.empty();
  });
  if (missing_rescale && series.is_ct)
    log::warn("DICOM: some slices of series {} have no RescaleSlope/Intercept nor Modality LUT; taking stored values "
              "as HU (slope 1, intercept 0)",
              series.uid);
  Volume volume = allocate_volume(layout, series);
  read_pixels(files, frames, layout, volume);
  return volume;
}
}  // namespace vx
