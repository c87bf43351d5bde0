// Command-line mistakes with the nearest correct word (usage.h).
#include "usage.h"

#include <fmt/format.h>

#include <algorithm>
#include <filesystem>
#include <string>
#include <vector>

#include "base/error.h"
#include "convert/phantom.h"
#include "convert/threshold.h"
#include "util/text.h"

namespace vx::cli {
namespace {

std::vector<std::string> subcommand_names(const CLI::App& app) {
  std::vector<std::string> names;
  for (const CLI::App* s : app.get_subcommands([](const CLI::App*) { return true; })) names.push_back(s->get_name());
  return names;
}

/// "--name" for each long option of `app`.
void add_long_options(const CLI::App& app, std::vector<std::string>& out) {
  for (const CLI::Option* o : app.get_options())
    for (const std::string& n : o->get_lnames()) out.push_back("--" + n);
}

bool known_long_option(const std::vector<std::string>& known, const std::string& word) {
  return std::find(known.begin(), known.end(), word) != known.end();
}

}  // namespace

std::string unknown_subcommand_message(const CLI::App& app, int argc, const char* const* argv) {
  for (int i = 1; i < argc; ++i) {
    const std::string w = argv[i];
    if (w.empty() || w[0] == '-') continue;  // -q, -v, --help, --version take no value
    const std::vector<std::string> names = subcommand_names(app);
    if (std::find(names.begin(), names.end(), w) != names.end()) return "";
    std::string list;
    for (const auto& n : names) list += (list.empty() ? "" : ", ") + n;
    const std::string near = nearest_word(w, names);
    return fmt::format("unknown command '{}'{}; the commands are: {} (voxelastic COMMAND --help for each)", w,
                       near.empty() ? std::string() : " (did you mean '" + near + "'?)", list);
  }
  return "";
}

std::string option_suggestion(const CLI::App& app, int argc, const char* const* argv) {
  // the options of the subcommand given and of the app (-q, -v anywhere)
  std::vector<std::string> known;
  add_long_options(app, known);
  for (const CLI::App* s : app.get_subcommands([](const CLI::App*) { return true; })) {
    bool given = false;
    for (int i = 1; i < argc; ++i) given = given || s->get_name() == argv[i];
    if (given) add_long_options(*s, known);
  }
  for (int i = 1; i < argc; ++i) {
    std::string w = argv[i];
    if (w.rfind("--", 0) != 0 || w == "--") continue;
    w = w.substr(0, w.find('='));
    if (known_long_option(known, w)) continue;
    const std::string near = nearest_word(w, known);
    if (!near.empty()) return fmt::format("unknown option '{}'; did you mean '{}'?", w, near);
  }
  return "";
}

std::vector<std::string> hyphenated_long_options(int argc, const char* const* argv) {
  std::vector<std::string> out(argv, argv + argc);
  for (std::size_t i = 1; i < out.size(); ++i) {
    std::string& w = out[i];
    if (w == "--") break;  // the rest are operands
    if (w.rfind("--", 0) != 0) continue;
    std::replace(w.begin(), std::find(w.begin(), w.end(), '='), '_', '-');
  }
  return out;
}

CLI::Validator threshold_check() {
  return CLI::Validator(
      [](std::string& text) {
        try {
          (void)parse_threshold(text);
          return std::string();
        } catch (const Error& e) {
          return std::string(e.what());
        }
      },
      "LO[:HI]|PRESET");
}

CLI::Validator phantom_name_check() {
  return CLI::Validator(
      [](std::string& name) {
        const std::vector<std::string> names = phantom_names();
        if (std::find(names.begin(), names.end(), name) != names.end()) return std::string();
        std::string list;
        for (const auto& n : names) list += (list.empty() ? "" : ", ") + n;
        const std::string near = nearest_word(name, names);
        return fmt::format("unknown phantom '{}'{} (choose one of: {})", name,
                           near.empty() ? std::string() : "; did you mean '" + near + "'?", list);
      },
      "NAME");
}

CLI::Validator extension_check(const std::string& ext, const std::string& what) {
  return CLI::Validator(
      [ext, what](std::string& path) {
        // by the name's ending, so a double extension (".seg.nrrd") is checked whole
        const std::filesystem::path p(path);
        const std::string name = p.filename().string();
        if (name.size() > ext.size() && name.ends_with(ext)) return std::string();
        const std::string stem = p.stem().string().empty() ? "out" : p.stem().string();
        return fmt::format("'{}': the {} must be a {} file (for example {})", path, what, ext,
                           (p.parent_path() / (stem + ext)).string());
      },
      "*" + ext);
}

}  // namespace vx::cli
