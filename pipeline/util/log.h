#pragma once
/// @file log.h
/// What the programs say besides their results, by level (spdlog underneath): notes and
/// progress at `info`, warnings at `warn`, details at `debug`. Everything goes to stderr;
/// results (summaries) go to stdout and are not logged. `-q` sets the level to `warn`
/// (warnings and errors still show), `-v` to `debug`.

#include <fmt/format.h>

#include <string>
#include <string_view>
#include <utility>

namespace vx::log {

enum class Level { debug, info, warn, error, off };

/// The level below which messages are dropped (default: info).
void set_level(Level level);
[[nodiscard]] Level level();
/// True when messages of `l` are shown (e.g. whether to draw progress).
[[nodiscard]] bool enabled(Level l);

/// A note ("DICOM: reading series ..."), printed as is.
void info(std::string_view text);
/// A warning, printed as "warning: text".
void warn(std::string_view text);
/// A detail for -v, printed as "debug: text".
void debug(std::string_view text);

template <typename... A>
void info(fmt::format_string<A...> f, A&&... a) {
  if (enabled(Level::info)) info(std::string_view(fmt::format(f, std::forward<A>(a)...)));
}
template <typename... A>
void warn(fmt::format_string<A...> f, A&&... a) {
  if (enabled(Level::warn)) warn(std::string_view(fmt::format(f, std::forward<A>(a)...)));
}
template <typename... A>
void debug(fmt::format_string<A...> f, A&&... a) {
  if (enabled(Level::debug)) debug(std::string_view(fmt::format(f, std::forward<A>(a)...)));
}

}  // namespace vx::log
