#pragma once
/// @file atomic_file.h
/// Write outputs all-or-nothing: write to a temporary file beside the target, then rename.

#include <filesystem>
#include <functional>
#include <string>

namespace vx {

/// How hard a write insists on reaching the disk.
enum class Durability {
  /// fsync the file before the rename and its folder after: the target survives a power loss
  /// as either the old or the new file (the default: a few ms per file)
  power_loss,
  /// rename only: safe against crashes of the program, not of the machine (frames of a time
  /// series, hundreds per run, whose collection file is written durably at the end)
  process_crash,
};

/// Calls `write(tmp_path)` with a temporary path in the target's folder, then renames it
/// onto `path`. On any failure (exception, or the temporary file missing afterwards) the
/// temporary file is removed, nothing is left at `path` that was not there before, and a
/// vx::Error says what failed. The temporary name keeps the target's extension, so writers
/// that pick the format from the extension still work.
void write_atomically(const std::filesystem::path& path,
                      const std::function<void(const std::filesystem::path& tmp)>& write,
                      Durability durability = Durability::power_loss);

/// fsync of a written file (its data and size on disk); throws vx::Error when it fails.
void sync_file(const std::filesystem::path& path);
/// fsync of a folder (the names in it: a rename reaches the disk); errors are ignored (some
/// file systems cannot sync folders).
void sync_folder(const std::filesystem::path& folder);

/// Writes `text` to `path` atomically.
void write_text_atomically(const std::filesystem::path& path, const std::string& text);

/// Throws vx::Error unless the folder that will hold `path` exists and is writable.
void check_output_path(const std::filesystem::path& path);

}  // namespace vx
