// Reading a DICOM CT series into a float HU volume (DCMTK).
//
// Two passes keep memory at about the size of the volume: headers first (each file loaded
// with a read-length limit, so pixel data stays on disk: dicom_header.cpp), then the pixels
// of the chosen series frame by frame straight into the float volume (dicom_pixels.cpp). This
// file finds the files, groups them into series and chooses one; dicom_slice_layout.cpp sorts
// and checks its slices. What the passes hand each other: dicom_series_parts.h.

#include "io/dicom_series.h"

#include <fmt/format.h>

#include <algorithm>
#include <map>

#include "base/error.h"
#include "io/dicom_common.h"
#include "io/dicom_series_parts.h"
#include "util/log.h"
#include "util/text.h"

namespace vx {
namespace dicom {

std::string SeriesInfo::label() const {
  return fmt::format("{} ({}, {} image{}{})", uid, modality.empty() ? "no modality" : modality, frames,
                     frames == 1 ? "" : "s", description.empty() ? "" : ", '" + description + "'");
}

namespace {
namespace fs = std::filesystem;

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
        throw Error(fmt::format(
            "DICOM: folder {} holds no files (point to the folder that holds the series' .dcm files)", quoted(input)));
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

std::string list_series(const std::vector<const SeriesInfo*>& series) {
  std::string s;
  for (const SeriesInfo* si : series) s += "\n  " + si->label();
  return s;
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
      throw Error(
          fmt::format("DICOM: {} holds only localizer (scout) images ({}), no volume to read", where, localizers));
    throw Error(fmt::format("DICOM: {} holds no DICOM images", where));
  }
  const SeriesInfo* chosen = nullptr;
  if (!options.series_uid.empty()) {
    for (const SeriesInfo* s : series)
      if (s->uid == options.series_uid) chosen = s;
    if (!chosen)
      throw Error(
          fmt::format("DICOM: series {} is not in {}; the series found are:{}\n(pass one of these UIDs to --series)",
                      options.series_uid, where, list_series(series)));
    if (!chosen->is_ct && !options.any_modality)
      throw Error(
          fmt::format("DICOM: series {} is not CT ({}), so its values are not Hounsfield units; "
                      "pass --modality any (in a scene: \"any_modality\": true) to read it anyway",
                      chosen->uid, chosen->modality.empty() ? "unknown modality" : chosen->modality));
  } else {
    for (const SeriesInfo* s : series)
      if (s->is_ct || options.any_modality) {
        chosen = s;
        break;
      }
    if (!chosen)
      throw Error(
          fmt::format("DICOM: {} holds no CT series, only:{}\nThese values are not Hounsfield units; pass "
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
        throw Error(fmt::format("DICOM: cannot read {}: {}", quoted(one.path),
                                one.problem.empty() ? "it holds no image" : one.problem));
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
    throw Error(
        fmt::format("DICOM: {} holds {} file{}, none of them DICOM (e.g. {}: {}); point to the folder "
                    "that holds the series' .dcm files",
                    where, files.size(), files.size() == 1 ? "" : "s", quoted(not_dicom.front()->path),
                    not_dicom.front()->problem));
  if (!not_dicom.empty())
    log::info("DICOM: skipped {} file{} that {} not DICOM:{}", not_dicom.size(), not_dicom.size() == 1 ? "" : "s",
              not_dicom.size() == 1 ? "is" : "are", name_files(not_dicom));
  if (!unknown_broken.empty())
    log::warn(
        "DICOM: skipped {} unreadable DICOM file{} whose series cannot be told (if one belongs to the series "
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
      throw Error(
          fmt::format("DICOM: cannot read {} of series {}: {}; replace the file (re-export the series) or "
                      "remove it",
                      quoted(f.path), series.uid, f.problem));
    if (!f.xfer_decodable)
      throw Error(
          fmt::format("DICOM: {} uses transfer syntax '{}' ({}), which voxelastic cannot decode (RLE, JPEG "
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

}  // namespace
}  // namespace dicom

Volume read_dicom_series(const std::vector<std::filesystem::path>& inputs, const ReadOptions& options) {
  using namespace dicom;
  init_dcmtk();
  ReadOptions opts = options;
  std::string where = inputs.size() == 1 ? quoted(inputs.front()) : fmt::format("the {} inputs given", inputs.size());
  bool recursive = true;
  const std::vector<std::filesystem::path> resolved = resolve_single_file(inputs, opts, where, recursive);
  std::vector<FileInfo> files = read_headers(collect_files(resolved, recursive));
  const std::vector<const FileInfo*> unreadable = check_files(files, where);
  const std::map<std::string, SeriesInfo> all = group_series(files);
  const SeriesInfo& series = choose_series(all, opts, where);
  std::vector<const FileInfo*> broken_elsewhere;
  for (const FileInfo& f : files)
    if (f.kind == FileKind::broken && !f.series_uid.empty() && f.series_uid != series.uid)
      broken_elsewhere.push_back(&f);
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
      throw Error(fmt::format("{}\nDICOM: {} unreadable file{} {} skipped; the missing slice may be among them:{}",
                              e.what(), unreadable.size(), unreadable.size() == 1 ? "" : "s",
                              unreadable.size() == 1 ? "was" : "were", name_files(unreadable)));
    }
  }();
  const bool missing_rescale = std::any_of(
      frames.begin(), frames.end(), [&](const FrameInfo& fr) { return !fr.has_rescale && files[fr.file].lut.empty(); });
  if (missing_rescale && series.is_ct)
    log::warn(
        "DICOM: some slices of series {} have no RescaleSlope/Intercept nor Modality LUT; taking stored values "
        "as HU (slope 1, intercept 0)",
        series.uid);
  Volume volume = allocate_volume(layout, series, opts.max_volume_bytes);
  read_pixels(files, frames, layout, volume);
  return volume;
}
}  // namespace vx
