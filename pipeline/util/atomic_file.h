#pragma once
/// @file atomic_file.h
/// Write outputs all-or-nothing: write to a temporary file beside the target, then rename.

#include <filesystem>
#include <functional>
#include <string>

namespace vx {

/// Calls `write(tmp_path)` with a temporary path in the target's folder, then renames it
/// onto `path`. On any failure (exception, or the temporary file missing afterwards) the
/// temporary file is removed, nothing is left at `path` that was not there before, and a
/// vx::Error says what failed. The temporary name keeps the target's extension, so writers
/// that pick the format from the extension still work.
void write_atomically(const std::filesystem::path& path,
                      const std::function<void(const std::filesystem::path& tmp)>& write);

/// Writes `text` to `path` atomically.
void write_text_atomically(const std::filesystem::path& path, const std::string& text);

/// Throws vx::Error unless the folder that will hold `path` exists and is writable.
void check_output_path(const std::filesystem::path& path);

}  // namespace vx
