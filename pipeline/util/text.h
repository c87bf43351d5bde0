#pragma once
/// @file text.h
/// Small text helpers the readers and parsers share: trimming, lower case, a path quoted
/// for an error message, and the nearest known word for "did you mean ...?".

#include <cstddef>
#include <filesystem>
#include <string>
#include <vector>

namespace vx {

/// `s` without leading and trailing white space (std::isspace: blanks, tabs, line breaks).
[[nodiscard]] std::string trim(const std::string& s);

/// `s` in lower case (ASCII letters only; other bytes unchanged).
[[nodiscard]] std::string lower(std::string s);

/// The path in single quotes, as messages name files: 'dir/file.nrrd'.
[[nodiscard]] std::string quoted(const std::filesystem::path& path);

/// Levenshtein distance: the fewest single-character insertions, deletions and substitutions
/// that turn `a` into `b` (case-sensitive).
[[nodiscard]] std::size_t edit_distance(const std::string& a, const std::string& b);

/// The word of `known` nearest to `typed` (case-insensitive), if it is closer than
/// `max_distance` edits; else "". The first of equally near words wins. For messages:
/// "unknown key \"densty\"; did you mean \"density\"?".
[[nodiscard]] std::string nearest_word(const std::string& typed, const std::vector<std::string>& known,
                                       std::size_t max_distance = 3);

}  // namespace vx
