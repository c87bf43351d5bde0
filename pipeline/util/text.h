#pragma once
/// @file text.h
/// Small text helpers the readers and parsers share: trimming, lower case, and a path quoted
/// for an error message.

#include <filesystem>
#include <string>

namespace vx {

/// `s` without leading and trailing white space (std::isspace: blanks, tabs, line breaks).
[[nodiscard]] std::string trim(const std::string& s);

/// `s` in lower case (ASCII letters only; other bytes unchanged).
[[nodiscard]] std::string lower(std::string s);

/// The path in single quotes, as messages name files: 'dir/file.nrrd'.
[[nodiscard]] std::string quoted(const std::filesystem::path& path);

}  // namespace vx
