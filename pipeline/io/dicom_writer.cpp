// Writing a volume as a synthetic CT Image Storage series (DCMTK): one file per slice,
// valid for dciodvfy, in a chosen transfer syntax. All or nothing: the series is written into
// a temporary sibling folder, then renamed into place.

#include <dcmtk/config/osconfig.h>
#include <dcmtk/dcmdata/dcdeftag.h>
#include <dcmtk/dcmdata/dcfilefo.h>
#include <dcmtk/dcmdata/dcrlerp.h>
#include <dcmtk/dcmdata/dcuid.h>
#include <dcmtk/dcmjpeg/djrplol.h>
#include <dcmtk/dcmjpls/djrparam.h>
#include <fmt/format.h>
#include <unistd.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <atomic>
#include <cmath>
#include <ctime>
#include <memory>
#include <regex>

#include "base/error.h"
#include "io/dicom_common.h"
#include "io/dicom_series.h"
#include "io/jpeg2000.h"
#include "util/atomic_file.h"

namespace vx {
namespace {
namespace fs = std::filesystem;

/// A transfer syntax the writer offers, with the DCMTK representation parameters it needs.
struct WriteSyntax {
  E_TransferSyntax xfer{EXS_LittleEndianExplicit};
  std::unique_ptr<DcmRepresentationParameter> parameters;  ///< null for uncompressed syntaxes
};

WriteSyntax pick_syntax(const std::string& name) {
  WriteSyntax s;
  if (name == "explicit-little") {
    s.xfer = EXS_LittleEndianExplicit;
  } else if (name == "implicit-little") {
    s.xfer = EXS_LittleEndianImplicit;
  } else if (name == "rle") {
    s.xfer = EXS_RLELossless;
    s.parameters = std::make_unique<DcmRLERepresentationParameter>();
  } else if (name == "jpeg-lossless") {
    s.xfer = EXS_JPEGProcess14SV1;
    s.parameters = std::make_unique<DJ_RPLossless>(1, 0);
  } else if (name == "jpeg-ls-lossless") {
    s.xfer = EXS_JPEGLSLossless;
    s.parameters = std::make_unique<DJLSRepresentationParameter>(0, OFTrue);
  } else if (name == "jpeg2000-lossless") {
    s.xfer = EXS_JPEG2000LosslessOnly;
    s.parameters = dicom::jpeg2000_parameter(true);
  } else if (name == "jpeg2000") {
    s.xfer = EXS_JPEG2000;
    s.parameters = dicom::jpeg2000_parameter(false, 8.0);
  } else {
    throw Error(fmt::format("DICOM: unknown transfer syntax '{}' for writing; choose explicit-little, "
                            "implicit-little, rle, jpeg-lossless, jpeg-ls-lossless, jpeg2000-lossless or jpeg2000 "
                            "(lossy, 8:1)",
                            name));
  }
  return s;
}

std::string new_uid(const char* root) {
  char buf[100];
  return dcmGenerateUniqueIdentifier(buf, root);
}

/// How HU map to stored unsigned 16-bit values: hu = stored * slope + intercept.
struct Rescale {
  double slope{1.0};
  double intercept{-1024.0};
};

Rescale choose_rescale(const std::vector<float>& hu) {
  float lo = std::numeric_limits<float>::infinity(), hi = -lo;
  for (float v : hu) {
    if (!std::isfinite(v))
      throw Error("DICOM: the volume holds NaN or infinite values, which a DICOM series cannot store; "
                  "replace them (e.g. with -1000 HU) first");
    lo = std::min(lo, v);
    hi = std::max(hi, v);
  }
  Rescale r;
  const double flo = std::floor(double(lo)), chi = std::ceil(double(hi));
  if (chi - flo <= 65535.0) {
    // slope 1: integer HU are stored exactly; the usual -1024 intercept when it fits
    r.intercept = (flo >= -1024.0 && chi + 1024.0 <= 65535.0) ? -1024.0 : flo;
  } else {
    r.slope = (double(hi) - double(lo)) / 65535.0;
    r.intercept = double(lo);
  }
  return r;
}

std::string ds_list(std::initializer_list<double> values) {
  std::string s;
  for (double v : values) {
    if (!s.empty()) s.push_back('\\');
    s.append(dicom::format_ds(v));
  }
  return s;
}

void check(const OFCondition& status, const char* what) {
  if (status.bad()) throw Error(fmt::format("DICOM: cannot set {}: {}", what, status.text()));
}

/// The folder a path names ("out/" and "out" are the same folder).
fs::path folder_of(const fs::path& p) {
  fs::path f = p;
  while (!f.empty() && f.filename().empty() && f.has_parent_path() && f != f.parent_path()) f = f.parent_path();
  return f;
}

bool is_slice_file_name(const std::string& name) {
  static const std::regex pattern(R"(slice_\d+\.dcm)");
  return std::regex_match(name, pattern);
}

}  // namespace

void write_dicom_series(const Volume& volume, const fs::path& folder_in, const DicomWriteSettings& settings) {
  dicom::init_dcmtk();
  const fs::path folder = folder_of(folder_in);
  if (folder.empty()) throw Error("DICOM: no output folder given for the series");
  const GridGeometry& g = volume.geometry;

  // check the volume before touching the disk
  if ((g.dims.array() <= 0).any())
    throw Error(fmt::format("DICOM: cannot write an empty volume ({} x {} x {} voxels) to '{}'", g.dims.x(), g.dims.y(),
                            g.dims.z(), folder.string()));
  if (g.dims.x() > 65535 || g.dims.y() > 65535)
    throw Error(fmt::format("DICOM: slices of {} x {} pixels do not fit DICOM's 16-bit Rows/Columns", g.dims.x(), g.dims.y()));
  if (std::int64_t(volume.hu.size()) != g.voxel_count())
    throw Error(fmt::format("DICOM: the volume has {} values for {} voxels", volume.hu.size(), g.voxel_count()));
  if ((g.spacing_mm.array() <= 0).any() || !g.spacing_mm.allFinite())
    throw Error("DICOM: the volume's voxel spacing must be positive to write it");
  const Eigen::Vector3d row = g.direction.col(0), col = g.direction.col(1), axis = g.direction.col(2);
  if (std::abs(row.norm() - 1) > 1e-6 || std::abs(col.norm() - 1) > 1e-6 || std::abs(row.dot(col)) > 1e-6)
    throw Error("DICOM: the volume's first two direction axes must be orthonormal (ImageOrientationPatient); "
                "resample the volume first");
  const Eigen::Vector3d normal = row.cross(col);
  if (axis.norm() < 1e-9 || std::abs(axis.normalized().dot(normal)) < 0.1)
    throw Error("DICOM: the volume's slice axis lies (almost) in the slice plane; cannot write it as slices");
  WriteSyntax syntax = pick_syntax(settings.transfer_syntax);
  const Rescale rescale = choose_rescale(volume.hu);

  // the output folder: new, empty, or holding only an earlier series of ours
  std::error_code ec;
  const fs::path parent = folder.has_parent_path() ? folder.parent_path() : fs::path(".");
  if (!fs::is_directory(parent, ec))
    throw Error(fmt::format("DICOM: cannot write series to '{}': '{}' {}", folder.string(), parent.string(),
                            fs::exists(parent, ec) ? "is a file, not a folder (choose another output folder)"
                                                   : "does not exist (create it first)"));
  if (::access(parent.c_str(), W_OK) != 0)
    throw Error(fmt::format("DICOM: cannot write series to '{}': folder '{}' is not writable (choose another output "
                            "folder or fix its permissions)",
                            folder.string(), parent.string()));
  bool replace = false;
  if (fs::exists(folder, ec)) {
    if (!fs::is_directory(folder, ec))
      throw Error(fmt::format("DICOM: cannot write series to '{}': it is a file, not a folder", folder.string()));
    for (const auto& entry : fs::directory_iterator(folder, ec)) {
      if (!entry.is_regular_file() || !is_slice_file_name(entry.path().filename().string()))
        throw Error(fmt::format("DICOM: cannot write series to '{}': the folder holds other files (e.g. '{}'); "
                                "give a new or empty folder",
                                folder.string(), entry.path().filename().string()));
      replace = true;
    }
  }

  // shared identity of the series
  const std::string study_uid = new_uid(SITE_STUDY_UID_ROOT);
  const std::string series_uid = new_uid(SITE_SERIES_UID_ROOT);
  const std::string frame_uid = new_uid(SITE_INSTANCE_UID_ROOT);
  char date[16], time[16];
  const std::time_t now = std::time(nullptr);
  std::tm tm{};
  localtime_r(&now, &tm);
  std::strftime(date, sizeof date, "%Y%m%d", &tm);
  std::strftime(time, sizeof time, "%H%M%S", &tm);
  const bool utf8 = std::any_of(settings.patient_name.begin(), settings.patient_name.end(), [](char c) { return c & 0x80; }) ||
                    std::any_of(settings.series_description.begin(), settings.series_description.end(),
                                [](char c) { return c & 0x80; });
  const int nx = g.dims.x(), ny = g.dims.y(), nz = g.dims.z();
  const int digits = std::max(4, int(std::to_string(nz).size()));
  const std::string orientation = ds_list({row.x(), row.y(), row.z(), col.x(), col.y(), col.z()});
  const std::string pixel_spacing = ds_list({g.spacing_mm.y(), g.spacing_mm.x()});  // row spacing \ column spacing
  const double thickness = g.spacing_mm.z() * std::abs(axis.normalized().dot(normal));

  static std::atomic<unsigned> counter{0};
  const std::string name = folder.filename().string();
  const fs::path tmp = parent / ("." + name + ".tmp" + std::to_string(::getpid()) + "_" + std::to_string(counter++));
  const fs::path old = parent / ("." + name + ".old" + std::to_string(::getpid()) + "_" + std::to_string(counter++));
  try {
    if (!fs::create_directory(tmp, ec) || ec)
      throw Error(fmt::format("cannot create temporary folder '{}': {}", tmp.string(), ec.message()));
    std::vector<Uint16> stored(std::size_t(nx) * std::size_t(ny));
    for (int k = 0; k < nz; ++k) {
      DcmFileFormat file;
      DcmDataset* ds = file.getDataset();
      const Eigen::Vector3d position = g.origin_mm + axis * (g.spacing_mm.z() * k);
      const std::string sop_uid = new_uid(SITE_INSTANCE_UID_ROOT);
      auto put = [&](const DcmTagKey& tag, const std::string& value) {
        check(ds->putAndInsertString(tag, value.c_str()), DcmTag(tag).getTagName());
      };
      auto put16 = [&](const DcmTagKey& tag, Uint16 value) {
        check(ds->putAndInsertUint16(tag, value), DcmTag(tag).getTagName());
      };
      // SOP common
      if (utf8) put(DCM_SpecificCharacterSet, "ISO_IR 192");
      put(DCM_SOPClassUID, UID_CTImageStorage);
      put(DCM_SOPInstanceUID, sop_uid);
      put(DCM_InstanceCreationDate, date);
      put(DCM_InstanceCreationTime, time);
      // patient
      put(DCM_PatientName, settings.patient_name);
      put(DCM_PatientID, "VOXELASTIC");
      put(DCM_PatientBirthDate, "");
      put(DCM_PatientSex, "");
      // general study
      put(DCM_StudyInstanceUID, study_uid);
      put(DCM_StudyDate, date);
      put(DCM_StudyTime, time);
      put(DCM_ReferringPhysicianName, "");
      put(DCM_StudyID, "1");
      put(DCM_AccessionNumber, "");
      // general series
      put(DCM_Modality, "CT");
      put(DCM_SeriesInstanceUID, series_uid);
      put(DCM_SeriesNumber, "1");
      put(DCM_SeriesDescription, settings.series_description);
      put(DCM_Laterality, "");
      put(DCM_PatientPosition, "HFS");
      // frame of reference
      put(DCM_FrameOfReferenceUID, frame_uid);
      put(DCM_PositionReferenceIndicator, "");
      // general equipment
      put(DCM_Manufacturer, "voxelastic");
      // general image
      put(DCM_InstanceNumber, std::to_string(k + 1));
      put(DCM_PatientOrientation, "");
      put(DCM_ContentDate, date);
      put(DCM_ContentTime, time);
      put(DCM_ImageType, "DERIVED\\SECONDARY\\AXIAL");
      put(DCM_DerivationDescription, "synthetic volume written by voxelastic");
      // image plane
      put(DCM_PixelSpacing, pixel_spacing);
      put(DCM_ImageOrientationPatient, orientation);
      put(DCM_ImagePositionPatient, ds_list({position.x(), position.y(), position.z()}));
      put(DCM_SliceThickness, dicom::format_ds(thickness));
      put(DCM_SliceLocation, dicom::format_ds(position.dot(normal)));
      // CT image
      put(DCM_RescaleIntercept, dicom::format_ds(rescale.intercept));
      put(DCM_RescaleSlope, dicom::format_ds(rescale.slope));
      put(DCM_RescaleType, "HU");
      put(DCM_KVP, "");
      put(DCM_AcquisitionNumber, "1");
      put(DCM_WindowCenter, "40");
      put(DCM_WindowWidth, "400");
      // image pixel
      put16(DCM_SamplesPerPixel, 1);
      put(DCM_PhotometricInterpretation, "MONOCHROME2");
      put16(DCM_Rows, Uint16(ny));
      put16(DCM_Columns, Uint16(nx));
      put16(DCM_BitsAllocated, 16);
      put16(DCM_BitsStored, 16);
      put16(DCM_HighBit, 15);
      put16(DCM_PixelRepresentation, 0);
      const float* slice = volume.hu.data() + std::size_t(k) * stored.size();
      for (std::size_t p = 0; p < stored.size(); ++p)
        stored[p] = Uint16(std::clamp(std::lround((double(slice[p]) - rescale.intercept) / rescale.slope), 0L, 65535L));
      check(ds->putAndInsertUint16Array(DCM_PixelData, stored.data(), unsigned(stored.size())), "PixelData");
      if (syntax.parameters) {
        const OFCondition status = ds->chooseRepresentation(syntax.xfer, syntax.parameters.get());
        if (status.bad() || !ds->canWriteXfer(syntax.xfer))
          throw Error(fmt::format("cannot compress slice {} as {}: {}", k + 1, settings.transfer_syntax,
                                  status.bad() ? status.text() : "no encoder"));
      }
      const fs::path path = tmp / fmt::format("slice_{:0{}d}.dcm", k + 1, digits);
      const OFCondition status = file.saveFile(path.c_str(), syntax.xfer);
      if (status.bad())
        throw Error(fmt::format("cannot write '{}': {} (disk full?)", path.filename().string(), status.text()));
      sync_file(path);  // on disk before the folder is renamed into place
    }
    sync_folder(tmp);
    // into place; an earlier series of ours is swapped out, then removed
    if (replace) {
      fs::rename(folder, old, ec);
      if (ec) throw Error(fmt::format("cannot move the earlier series aside: {}", ec.message()));
    }
    fs::rename(tmp, folder, ec);
    if (ec) {
      const std::string why = ec.message();
      if (replace) fs::rename(old, folder, ec);
      throw Error(fmt::format("cannot rename the finished series into place: {}", why));
    }
    sync_folder(folder.parent_path());
    if (replace) fs::remove_all(old, ec);
  } catch (const std::exception& e) {
    fs::remove_all(tmp, ec);
    throw Error(fmt::format("DICOM: could not write series to '{}': {}", folder.string(), e.what()));
  }
}

}  // namespace vx
