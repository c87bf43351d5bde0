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
  std::vector<FrameInfo> frames;
};

std::string get_string(DcmItem* item, const DcmTagKey& tag) {
  OFString s;
  if (item && item->findAndGetOFStringArray(tag, s).good()) return std::string(s.c_str());
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

/// Everything about a file except its pixel values.
FileInfo read_header(const fs::path& path, bool explicit_input, std::size_t file_index) {
  FileInfo f;
  f.path = path;
  f.explicit_input = explicit_input;
  const bool magic = dicom::has_dicm_magic(path);
  DcmFileFormat ff;
  const OFCondition status = ff.loadFile(path.c_str(), EXS_Unknown, EGL_noChange, kHeaderReadLimit, ERM_autoDetect);
  DcmDataset* ds = ff.getDataset();
  f.sop_class = trim(get_string(ds, DCM_SOPClassUID));
  f.series_uid = trim(get_string(ds, DCM_SeriesInstanceUID));
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
  f.modality = trim(get_string(ds, DCM_Modality));
  f.description = trim(get_string(ds, DCM_SeriesDescription));
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

  // frames: classic images have one; enhanced ones describe each in functional groups
  long frames = 1;
  if (get_int(ds, DCM_NumberOfFrames, value) && value > 1) frames = value;
  DcmItem* shared = nullptr;
  ds->findAndGetSequenceItem(DCM_SharedFunctionalGroupsSequence, shared, 0);
  DcmSequenceOfItems* per_frame_seq = nullptr;
  ds->findAndGetSequence(DCM_PerFrameFunctionalGroupsSequence, per_frame_seq);
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
                              "pass --modality any (ReadOptions::any_modality) to read it anyway",
                              chosen->uid, chosen->modality.empty() ? "unknown modality" : chosen->modality));
  } else {
    for (const SeriesInfo* s : series)
      if (s->is_ct || options.any_modality) {
        chosen = s;
        break;
      }
    if (!chosen)
      throw Error(fmt::format("DICOM: {} holds no CT series, only:{}\nThese values are not Hounsfield units; pass "
                              "--modality any (ReadOptions::any_modality) to read one anyway (the largest is taken, "
                              "or the one given with --series)",
                              where, list_series(series)));
  }
  std::vector<const SeriesInfo*> others;
  for (const SeriesInfo* s : series)
    if (s != chosen) others.push_back(s);
  if (!others.empty())
    std::fprintf(stderr, "DICOM: reading series %s\nDICOM: also found (choose with --series UID):%s\n",
                 chosen->label().c_str(), list_series(others).c_str());
  if (!chosen->is_ct)
    std::fprintf(stderr, "DICOM: warning: series %s is %s, not CT: its values are not Hounsfield units, choose the "
                 "threshold accordingly\n", chosen->uid.c_str(), chosen->modality.empty() ? "of unknown modality" : chosen->modality.c_str());
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
    std::fprintf(stderr, "DICOM: warning: %s has no patient position/orientation; slices are ordered by "
                 "InstanceNumber and placed on an axis-aligned grid\n", frame_name(files, *missing).c_str());
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
    std::fprintf(stderr, "DICOM: warning: no PixelSpacing in %s; assuming 1 mm pixels\n",
                 frame_name(files, frames.front()).c_str());
  if (frames.size() < 2)
    throw Error(fmt::format("DICOM: series {} has a single slice ({}); a 3D model needs at least 2 slices "
                            "(check that the whole series was exported, or choose another with --series)",
                            series.uid, frame_name(files, frames.front())));
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
    std::fprintf(stderr, "DICOM: ignored %zu duplicate cop%s of images already read\n", dropped, dropped == 1 ? "y" : "ies");
  frames = std::move(unique);
  if (frames.size() < 2)
    throw Error(fmt::format("DICOM: series {} has a single distinct slice; a 3D model needs at least 2", series.uid));

  // spacing: median difference, then every gap checked against it
  std::vector<double> gaps;
  for (std::size_t k = 1; k < frames.size(); ++k) gaps.push_back(frames[k].normal_position - frames[k - 1].normal_position);
  const double dz = median(gaps);
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
    std::fprintf(stderr, "DICOM: series %s is tilted by %.2f degrees (gantry tilt); resampling it onto an "
                 "orthogonal grid of %d x %d x %d voxels (samples outside the scan become air)\n",
                 series.uid.c_str(), angle, dims.x(), dims.y(), dims.z());
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
        std::fprintf(stderr, "DICOM: %s is one slice; reading its series from folder '%s'\n",
                     inputs.front().string().c_str(), folder.string().c_str());
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

/// Problems that are fatal whatever the series (named files that are not DICOM, broken files of
/// unknown series), and notes on the files skipped.
void check_files(const std::vector<FileInfo>& files, const std::string& where) {
  std::size_t not_dicom = 0, non_image = 0;
  const FileInfo* example_not_dicom = nullptr;
  for (const FileInfo& f : files) {
    if (f.kind == FileKind::not_dicom) {
      if (f.explicit_input) throw Error(fmt::format("DICOM: cannot read {}: {}", quoted(f.path), f.problem));
      ++not_dicom;
      if (!example_not_dicom) example_not_dicom = &f;
    }
    if (f.kind == FileKind::non_image) ++non_image;
    if (f.kind == FileKind::broken && f.series_uid.empty())
      throw Error(fmt::format("DICOM: cannot read {}: {}; it is not clear which series it belongs to, so remove or "
                              "replace it (re-export or copy the series again)",
                              quoted(f.path), f.problem));
  }
  if (not_dicom == files.size())
    throw Error(fmt::format("DICOM: {} holds {} file{}, none of them DICOM (e.g. {}: {}); point to the folder "
                            "that holds the series' .dcm files",
                            where, files.size(), files.size() == 1 ? "" : "s", quoted(example_not_dicom->path),
                            example_not_dicom->problem));
  if (not_dicom)
    std::fprintf(stderr, "DICOM: skipped %zu file%s that %s not DICOM (e.g. '%s')\n", not_dicom,
                 not_dicom == 1 ? "" : "s", not_dicom == 1 ? "is" : "are", example_not_dicom->path.string().c_str());
  if (non_image) std::fprintf(stderr, "DICOM: skipped %zu DICOM file%s without images (reports, DICOMDIR, ...)\n",
                              non_image, non_image == 1 ? "" : "s");
}

/// The series found, by SeriesInstanceUID (localizers counted apart).
std::map<std::string, SeriesInfo> group_series(const std::vector<FileInfo>& files) {
  std::map<std::string, SeriesInfo> all;
  for (std::size_t i = 0; i < files.size(); ++i) {
    const FileInfo& f = files[i];
    if (f.kind != FileKind::image && f.kind != FileKind::broken) continue;
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
      throw Error(fmt::format("DICOM: {} uses transfer syntax '{}' ({}), which DCMTK 3.6.7 cannot decode here "
                              "(RLE, JPEG incl. lossless and JPEG-LS are supported; JPEG 2000 is not). Convert the "
                              "series to an uncompressed syntax first, e.g. 'gdcmconv --raw in.dcm out.dcm' (GDCM) "
                              "or re-export it uncompressed from the PACS",
                              quoted(f.path), f.xfer_name, f.xfer_uid));
    if (!f.is_ct && series.is_ct)
      std::fprintf(stderr, "DICOM: warning: %s in CT series %s is not a CT image (SOP class %s)\n",
                   f.path.string().c_str(), series.uid.c_str(), f.sop_class.c_str());
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
  check_files(files, where);
  const std::map<std::string, SeriesInfo> all = group_series(files);
  const SeriesInfo& series = choose_series(all, opts, where);
  std::size_t broken_elsewhere = 0;
  for (const FileInfo& f : files) broken_elsewhere += f.kind == FileKind::broken && f.series_uid != series.uid;
  if (broken_elsewhere)
    std::fprintf(stderr, "DICOM: warning: skipped %zu unreadable file%s of other series\n", broken_elsewhere,
                 broken_elsewhere == 1 ? "" : "s");
  std::vector<FrameInfo> frames = series_frames(files, series);
  const SliceLayout layout = lay_out_slices(files, frames, series, opts);
  const bool missing_rescale = std::any_of(frames.begin(), frames.end(), [](const FrameInfo& fr) { return !fr.has_rescale; });
  if (missing_rescale && series.is_ct)
    std::fprintf(stderr, "DICOM: warning: some slices of series %s have no RescaleSlope/Intercept; taking stored "
                 "values as HU (slope 1, intercept 0)\n", series.uid.c_str());
  Volume volume = allocate_volume(layout, series);
  read_pixels(files, frames, layout, volume);
  return volume;
}
}  // namespace vx
