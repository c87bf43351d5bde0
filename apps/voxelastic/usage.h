#pragma once
/// @file usage.h
/// Command-line mistakes, told as such (exit code 2, util/exit_codes.h) with the nearest
/// correct word: an unknown subcommand or option, a threshold or phantom name that is a typo,
/// an output of the wrong kind. The words are compared by util/text.h's nearest_word, the
/// same as a scene file's unknown keys.

#include <CLI/CLI.hpp>

#include <string>
#include <vector>

namespace vx::cli {

/// The first word of the line that is not an option, when it names no subcommand of `app`
/// (the global options take no value): "unknown command 'conver'; did you mean 'convert'?".
/// Empty when the subcommand is known or absent.
[[nodiscard]] std::string unknown_subcommand_message(const CLI::App& app, int argc, const char* const* argv);

/// For a parse error on an unknown option: "did you mean '--threshold'?" for the first option
/// of the line that neither the subcommand given nor the app knows, if one is near; else "".
[[nodiscard]] std::string option_suggestion(const CLI::App& app, int argc, const char* const* argv);

/// The command line with each long option's '_' written '-' (`--fill_holes` -> `--fill-holes`;
/// the name only, before an '=', and nothing after a bare "--"): 3D Slicer runs a CLI module
/// with the <longflag>s of its description, which may hold no '-' (convert --xml).
[[nodiscard]] std::vector<std::string> hyphenated_long_options(int argc, const char* const* argv);

/// --threshold: a preset name or HU window (convert/threshold.h), checked while parsing.
[[nodiscard]] CLI::Validator threshold_check();

/// A phantom's name (convert/phantom.h), with the nearest name for a typo.
[[nodiscard]] CLI::Validator phantom_name_check();

/// An output file of one kind: its extension must be `ext` (".vtu"), `what` names the kind.
[[nodiscard]] CLI::Validator extension_check(const std::string& ext, const std::string& what);

}  // namespace vx::cli
