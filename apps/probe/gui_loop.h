#pragma once
/// @file gui_loop.h
/// The GUI thread's loop (the app's main thread, up to --fps passes per second): window events,
/// the deformed surface (frames requested from the physics and taken when ready, never waited
/// for), HUD, force plot, screenshots; headless, a status line every 2 s. It measures the rates
/// the HUD, the status lines and the final line show (real_time_meter.h) and sleeps to its next
/// frame deadline between passes: it never spins and holds no lock the physics needs while it
/// renders.

#include <memory>
#include <string>
#include <vector>

#include "app_shared.h"
#include "probe_view.h"
#include "real_time_meter.h"
#include "sim/simulation.h"
#include "soak.h"
#include "stick_control.h"

namespace vx::probe {

class GuiLoop {
 public:
  /// The window over which the HUD and the status lines measure the physics, s.
  static constexpr double kRateWindow_s = 1.0;
  /// Below this real-time factor over that window the tissue is behind real time (the HUD says so
  /// in red, and the display keeps to its frame budget).
  static constexpr double kBehindFactor = 0.95;
  /// With nothing new to draw (no physics frame, no input), the HUD and the force plot are
  /// redrawn this far apart, s; while the tissue runs behind real time, kHudRefreshBehind_s.
  static constexpr double kHudRefresh_s = 0.25;
  static constexpr double kHudRefreshBehind_s = 1.0;
  /// While the tissue runs behind real time, the display's frames take at most this share of
  /// the wall time (after a frame that took 0.1 s the next starts 0.1 / kBehindDuty s after it).
  /// Each is drawn in the display's turn (AppControls::display_turn), with the physics on one
  /// thread of two, about 0.4x its pace for the frame's time: at 0.12 about 5 % of the physics'
  /// pace, a frame about every 2 s on the folded organ under Xvfb (docs/probe.md, "Where the
  /// physics thread's time goes, and the display's turn").
  static constexpr double kBehindDuty = 0.12;

  GuiLoop(AppShared& shared, ProbeView* view, KeyboardStick& keyboard);
  /// The rates' first samples (device ticks, physics updates), taken before the window opens so
  /// that the first frame's rates span the opening (about a second on an organ), not nothing.
  void prime(const FixedRateThread& device);
  /// The window, once open (null: headless).
  void set_view(ProbeView* view) { view_ = view; }
  /// Runs until a quit; returns the error that ended it ("" for none). `interrupted` is polled
  /// (Ctrl-C, SIGTERM).
  [[nodiscard]] std::string run(const FixedRateThread& physics, const FixedRateThread& device,
                                const std::atomic<bool>& interrupted);
  /// A key's action (the view's callback).
  void on_action(ViewAction a);

  [[nodiscard]] bool window_closed() const { return window_closed_; }
  /// Wall time spent paused after the start-up, s (excluded from the final real-time factor).
  [[nodiscard]] double paused_s() const { return paused_s_; }
  /// Frames drawn in the display's turn (the tissue behind real time, the physics on one thread
  /// meanwhile; AppControls::display_turn), and their wall time, s.
  [[nodiscard]] std::int64_t display_turns() const { return display_turns_; }
  [[nodiscard]] double display_turns_s() const { return display_turns_s_; }
  /// Whether the window opened with a preview of the display surface (its decimation in the
  /// background), and when the decimated surface replaced it on screen, s since the open (-1:
  /// never: the run ended first).
  [[nodiscard]] bool opened_with_preview() const { return opened_with_preview_; }
  [[nodiscard]] double surface_replaced_s() const { return surface_replaced_s_; }
  /// When the first frame was on screen (its render ended), s since the open (-1: none drawn).
  [[nodiscard]] double first_frame_s() const { return first_frame_s_; }
  /// Soak: memory and the device's rate per second (soak.h).
  [[nodiscard]] const SoakMonitor& soak() const { return soak_; }

 private:
  /// The rates of this pass (device, updates, the physics' meter and its window_, behind_), input
  /// messages, the slow-motion warning; returns the pass's time.
  SteadyClock::time_point measure(const FixedRateThread& device);
  /// The physics' rate line: start-up, or steps/s and the real-time factor over the last second.
  [[nodiscard]] std::string physics_rate_text(SteadyClock::time_point now) const;
  /// While the solver is factored in the background (--background-factor): "factoring in the
  /// background (8 s since the open); the tissue rests till then"; else empty.
  [[nodiscard]] std::string solver_note(SteadyClock::time_point now) const;
  /// Says the background region check's result once it is ready (console; the HUD's status
  /// line when it warns).
  void report_region_check();
  /// Starts the display surface's background decimation once the solver is built; once it is
  /// ready, hands it to the physics (its frames then carry it, and take_frame swaps the view's
  /// triangles) and says so; a failed one is said and the preview stays.
  void take_refined_surface();
  /// While the display surface is a preview: "a preview (77287 triangles), decimated once the
  /// solver is built", then "a preview (77287 triangles) while decimating (25 s since the
  /// open)"; else empty.
  [[nodiscard]] std::string surface_note(SteadyClock::time_point now) const;
  /// Warns once when the physics cannot keep real time.
  void warn_if_behind(const RateWindow& w);
  /// One frame of the window; false once the window closed.
  bool show_frame(ProbeView& view, SteadyClock::time_point now);
  /// The newest deformed surface, if the physics made one since the last pass (true: taken).
  bool take_frame(ProbeView& view);
  /// Whether a frame of the tissue may be asked for and drawn now (the frame budget while the
  /// tissue runs behind real time).
  [[nodiscard]] bool frame_allowed(SteadyClock::time_point now) const;
  [[nodiscard]] HudInfo hud(SteadyClock::time_point now);
  /// Headless: a status line every 2 s.
  void report_headless(SteadyClock::time_point now);

  AppShared& s_;
  ProbeView* view_;
  KeyboardStick& keyboard_;
  RealTimeMeter meter_;
  RateMeter device_rate_{0.5}, update_rate_{0.5};
  SimulationFrame frame_;
  std::vector<Eigen::Vector3d> probe_pos_;
  std::vector<int> probe_contacts_;
  /// The surface the view draws (a frame that carries another has its triangles swapped in)
  std::shared_ptr<const EmbeddedSurface> shown_surface_;
  /// The preview's triangles while the background decimation runs (0: no preview)
  int preview_triangles_{0};
  bool opened_with_preview_{false};
  double surface_replaced_s_{-1.0};
  double first_frame_s_{-1.0};  ///< first_frame_s()
  bool window_closed_{false};
  bool warned_behind_{false};
  std::string region_status_;       ///< the region check's warning for the HUD (empty: none)
  double background_done_s_{-1.0};  ///< when the region check had ended (or none ran), wall s
  double paused_s_{0.0};
  SoakMonitor soak_;
  SteadyClock::time_point last_pass_{};
  SteadyClock::time_point last_render_{};
  double last_render_s_{0.0};       ///< the last frame's wall time, s
  std::int64_t display_turns_{0};   ///< frames drawn in the display's turn (AppControls::display_turn)
  double display_turns_s_{0.0};     ///< ... and their wall time, s
  RateWindow window_;               ///< the physics over the last kRateWindow_s, as of this pass
  bool behind_{false};              ///< running, not paused, and window_ below kBehindFactor
  std::int64_t rendered_input_{0};  ///< the view's input events at the last render
  SteadyClock::duration frame_period_;
  SteadyClock::time_point next_frame_{SteadyClock::now()};
  SteadyClock::time_point next_report_{SteadyClock::now() + std::chrono::seconds(2)};
};

}  // namespace vx::probe
