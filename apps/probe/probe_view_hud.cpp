// The probe view's texts and force plot: the heads-up display (rates, forces, warnings), the
// help, the displacement tint's legend, and the live force plot (the paper's fig. 10: the raw
// reaction sum, the half sines the device plays, and each device update's mean).
#include <fmt/core.h>
#include <vtkAxis.h>
#include <vtkBrush.h>
#include <vtkChartLegend.h>
#include <vtkChartXY.h>
#include <vtkContextActor.h>
#include <vtkContextScene.h>
#include <vtkCoordinate.h>
#include <vtkFloatArray.h>
#include <vtkPen.h>
#include <vtkPlot.h>
#include <vtkRenderWindow.h>
#include <vtkRenderer.h>
#include <vtkTable.h>
#include <vtkTextActor.h>
#include <vtkTextProperty.h>

#include <algorithm>

#include "probe_view_impl.h"

namespace vx::probe {
namespace {

constexpr const char* kHelp =
    "keys and mouse\n"
    "  arrows       move the probe (screen plane)\n"
    "  PgUp / PgDn  move it away / towards you\n"
    "  right-drag   move it (shift: depth)\n"
    "  left-drag    rotate the view, wheel: zoom\n"
    "  Tab          switch probe (keyboard)\n"
    "  l  element levels    t  see-through\n"
    "  d  displacement tint\n"
    "  w  walls             g  force plot\n"
    "  c  reset camera      r  reset scene\n"
    "  space  pause         s  screenshot\n"
    "  h  hide this help    q / Esc  quit";

}  // namespace

void set_text_style(vtkTextProperty* p, int size, const Rgb& c) {
  p->SetFontFamilyToCourier();
  p->SetFontSize(size);
  p->SetColor(c.r, c.g, c.b);
  p->SetBackgroundColor(0.0, 0.0, 0.0);
  p->SetBackgroundOpacity(0.45);
  p->SetShadow(false);
}

void ProbeView::Impl::build_hud() {
  tint_legend = make<vtkTextActor>();
  set_text_style(tint_legend->GetTextProperty(), 13, Rgb{0.95, 0.80, 0.76});
  tint_legend->SetInput(
      fmt::format("deeper red: tissue displaced (full at {:.1f} mm); d toggles", tint_full_mm).c_str());
  renderer->AddViewProp(tint_legend);
  hud = make<vtkTextActor>();
  set_text_style(hud->GetTextProperty(), 15, Rgb{0.95, 0.97, 1.0});
  hud->GetTextProperty()->SetVerticalJustificationToTop();
  renderer->AddViewProp(hud);
  status = make<vtkTextActor>();
  set_text_style(status->GetTextProperty(), 15, Rgb{1.0, 0.45, 0.40});
  status->GetTextProperty()->SetVerticalJustificationToTop();
  renderer->AddViewProp(status);
  help = make<vtkTextActor>();
  set_text_style(help->GetTextProperty(), 13, Rgb{0.85, 0.88, 0.92});
  help->GetTextProperty()->SetBackgroundOpacity(0.0);
  help->GetTextProperty()->SetVerticalJustificationToTop();
  help->SetInput(kHelp);
  help->GetPositionCoordinate()->SetCoordinateSystemToViewport();
  panel->AddViewProp(help);
}

void ProbeView::Impl::build_plot() {
  // per probe three columns: raw sum, half sine played, update mean
  table = make<vtkTable>();
  auto t = make<vtkFloatArray>();
  t->SetName("time (s)");
  table->AddColumn(t);
  const int np = std::min(2, std::max<int>(1, int(setup.probes.size())));
  for (int p = 0; p < np; ++p) {
    const std::string name = p < int(setup.probe_names.size()) ? setup.probe_names[std::size_t(p)] : std::to_string(p);
    const std::string who = np > 1 ? " (" + name + ")" : "";
    const std::array<const char*, 3> names =
        setup.local_shaping
            ? std::array<const char*, 3>{"raw sum per step", "device (local model, 1 kHz)", "physics update"}
            : std::array<const char*, 3>{"raw sum per step", "half sines played", "device update mean"};
    for (const char* name : names) {
      auto col = make<vtkFloatArray>();
      col->SetName((name + who).c_str());
      table->AddColumn(col);
    }
  }
  chart = make<vtkChartXY>();
  chart->SetAutoSize(false);
  chart->SetTitle("probe force |F| (N)");
  chart->GetTitleProperties()->SetColor(0.95, 0.95, 0.95);
  chart->GetTitleProperties()->SetFontSize(14);
  chart->GetBackgroundBrush()->SetColorF(0.05, 0.06, 0.08, 1.0);
  chart->SetShowLegend(true);
  chart->GetLegend()->GetLabelProperties()->SetColor(0.95, 0.95, 0.95);
  chart->GetLegend()->GetLabelProperties()->SetFontSize(11);
  chart->GetLegend()->GetBrush()->SetColorF(0.1, 0.1, 0.12, 0.75);
  chart->GetLegend()->SetInline(true);
  chart->GetLegend()->SetHorizontalAlignment(vtkChartLegend::LEFT);
  chart->GetLegend()->SetVerticalAlignment(vtkChartLegend::TOP);
  for (int a : {vtkAxis::LEFT, vtkAxis::BOTTOM}) {
    vtkAxis* axis = chart->GetAxis(a);
    axis->GetLabelProperties()->SetColor(0.9, 0.9, 0.9);
    axis->GetTitleProperties()->SetColor(0.9, 0.9, 0.9);
    axis->GetTitleProperties()->SetFontSize(12);
    axis->GetLabelProperties()->SetFontSize(12);
    axis->GetPen()->SetColorF(0.8, 0.8, 0.8);
    axis->GetGridPen()->SetColorF(0.25, 0.27, 0.31);
    axis->SetBehavior(vtkAxis::AUTO);
  }
  chart->GetAxis(vtkAxis::LEFT)->SetTitle("N");
  chart->GetAxis(vtkAxis::BOTTOM)->SetTitle(setup.local_shaping ? "time (s)" : "simulated time (s)");
  for (int p = 0; p < np; ++p) {
    const Rgb& c = kProbeColour[std::size_t(p)];
    vtkPlot* played = chart->AddPlot(vtkChart::LINE);
    played->SetInputData(table, 0, 2 + 3 * p);
    played->SetColor(c.r, c.g, c.b);
    // the half sines swing through zero 50 times a second: thin and faint; the local model's
    // force is what the hand feels: drawn over the physics' updates
    played->GetPen()->SetOpacityF(setup.local_shaping ? 1.0 : 0.35);
    played->SetWidth(setup.local_shaping ? 2.0 : 1.0);
    vtkPlot* raw = chart->AddPlot(vtkChart::LINE);
    raw->SetInputData(table, 0, 1 + 3 * p);
    raw->SetColor(0.85, 0.87, 0.90);
    raw->GetPen()->SetOpacityF(0.7);
    raw->SetWidth(1.0);
    vtkPlot* mean = chart->AddPlot(vtkChart::LINE);
    mean->SetInputData(table, 0, 3 + 3 * p);
    mean->SetColor(c.r, c.g, c.b);
    mean->SetWidth(3.0);
    if (setup.local_shaping) {
      mean->GetPen()->SetOpacityF(0.45);
      mean->SetWidth(4.0);
    }
  }
  auto scene = make<vtkContextScene>();
  scene->AddItem(chart);
  chart_actor = make<vtkContextActor>();
  chart_actor->SetScene(scene);
  panel->AddActor(chart_actor);
  scene->SetRenderer(panel);
}

void ProbeView::Impl::update_plot() {
  const int np = std::min(2, std::max<int>(1, int(setup.probes.size())));
  // a line needs two points: before the first samples, a flat zero line over the window
  std::deque<PlotSample> pad;
  if (plot.size() < 2) {
    PlotSample a, b;
    b.t_s = plot.empty() ? setup.plot_window_s : std::max(plot.back().t_s, 1e-3);
    pad = {a, b};
  }
  const std::deque<PlotSample>& data = plot.size() < 2 ? pad : plot;
  const auto n = vtkIdType(data.size());
  table->SetNumberOfRows(n);
  auto* t = vtkFloatArray::SafeDownCast(table->GetColumn(0));
  for (vtkIdType i = 0; i < n; ++i) {
    const PlotSample& s = data[std::size_t(i)];
    t->SetValue(i, float(s.t_s));
    for (int p = 0; p < np; ++p) {
      vtkFloatArray::SafeDownCast(table->GetColumn(1 + 3 * p))->SetValue(i, s.raw_N[std::size_t(p)]);
      vtkFloatArray::SafeDownCast(table->GetColumn(2 + 3 * p))->SetValue(i, s.device_N[std::size_t(p)]);
      vtkFloatArray::SafeDownCast(table->GetColumn(3 + 3 * p))->SetValue(i, s.mean_N[std::size_t(p)]);
    }
  }
  for (vtkIdType c = 0; c < table->GetNumberOfColumns(); ++c) table->GetColumn(c)->Modified();
  table->Modified();
  chart->RecalculateBounds();
  // a steady window: the last plot_window_s seconds, force from 0 with headroom
  vtkAxis* x = chart->GetAxis(vtkAxis::BOTTOM);
  vtkAxis* y = chart->GetAxis(vtkAxis::LEFT);
  const double t1 = plot.empty() ? setup.plot_window_s : std::max(setup.plot_window_s, plot.back().t_s);
  x->SetBehavior(vtkAxis::FIXED);
  x->SetRange(t1 - setup.plot_window_s, t1);
  float fmax = 0.0f;
  for (const auto& s : plot)
    for (int p = 0; p < np; ++p)
      fmax = std::max({fmax, s.device_N[std::size_t(p)], s.raw_N[std::size_t(p)], s.mean_N[std::size_t(p)]});
  // a range that only grows in steps, so the plot does not breathe every frame
  double top = 0.5;
  while (top < 1.1 * fmax) top *= 2.0;
  y->SetBehavior(vtkAxis::FIXED);
  y->SetRange(0.0, top);
  chart_actor->SetVisibility(plot_on);
}

void ProbeView::Impl::update_hud_text() {
  const HudInfo& h = hud_info;
  std::string text = fmt::format("{}   t = {:.2f} s{}\n", setup.title, h.sim_s, h.paused ? "   [PAUSED]" : "");
  // the solver's configuration on a line of its own: after the rate it ran under the plot
  std::string config = setup.physics_line.empty() ? std::string() : "  solver: " + setup.physics_line + "\n";
  if (!h.solver_note.empty()) config += "  solver: " + h.solver_note + "\n";
  if (!h.surface_note.empty()) config += "  display: " + h.surface_note + "\n";
  // sharing the cores: on one thread while the others are not needed (the display has them)
  const std::string threads =
      h.physics_threads_given > 1 ? fmt::format(", {} of {} threads", h.physics_threads, h.physics_threads_given) : "";
  if (setup.local_shaping) {
    // the physics updates the model; the device computes the force from it at its own rate
    const std::string rate = h.physics_rate.empty() ? fmt::format("{:.0f} steps/s (tissue {:.2f}x real time)",
                                                                  h.physics_steps_per_s, h.real_time_factor)
                                                    : h.physics_rate;
    text += fmt::format("physics {:.0f} updates/s, {}{}\n{}", h.physics_updates_per_s, rate, threads, config);
    text += fmt::format("device {:.0f} forces/s (local contact model)   display {:.1f} frames/s\n", h.device_hz,
                        fps.rate());
  } else {
    const std::string rate = h.physics_rate.empty() ? fmt::format("{:.0f} steps/s ({:.2f}x real time)",
                                                                  h.physics_steps_per_s, h.real_time_factor)
                                                    : h.physics_rate;
    text += fmt::format("physics {}{}\n{}", rate, threads, config);
    text += fmt::format("device {:.0f} updates/s   display {:.1f} frames/s\n", h.device_hz, fps.rate());
  }
  for (int p = 0; p < h.probes && p < 2; ++p) {
    const std::string name =
        std::size_t(p) < setup.probe_names.size() ? setup.probe_names[std::size_t(p)] : fmt::format("probe {}", p);
    if (setup.local_shaping)
      text += fmt::format("{}{}: force {:.3f} N  ({} nodes in contact, model of {})\n", name,
                          h.probes > 1 && p == h.active_probe ? " [keys]" : "", h.force_N[std::size_t(p)],
                          h.contacts[std::size_t(p)], h.model_nodes[std::size_t(p)]);
    else
      text += fmt::format("{}{}: force {:.3f} N  ({} nodes in contact)\n", name,
                          h.probes > 1 && p == h.active_probe ? " [keys]" : "", h.force_N[std::size_t(p)],
                          h.contacts[std::size_t(p)]);
  }
  text += setup.input_line;
  if (!setup.output_line.empty()) text += "\n" + setup.output_line;
  hud->SetInput(text.c_str());
  std::string warn;
  if (h.behind_real_time)
    warn = setup.local_shaping
               ? fmt::format("tissue behind real time: {:.2f}x (the tool and its force stay real time)",
                             h.real_time_factor)
               : fmt::format("physics cannot keep real time: {:.2f}x (slow motion)", h.real_time_factor);
  if (h.device_hz > 0 && h.device_hz < 0.9 * h.device_target_hz) {
    if (!warn.empty()) warn += "\n";
    warn += fmt::format("device thread late: {:.0f} of {:.0f} updates/s", h.device_hz, h.device_target_hz);
  }
  if (!h.status.empty()) {
    if (!warn.empty()) warn += "\n";
    warn += h.status;
  }
  status->SetInput(warn.c_str());
  status->SetVisibility(!warn.empty());
  // the warnings go under the HUD's lines (all of them: the solver's and the display's notes too)
  const int* size = window->GetSize();
  const int lines = 1 + int(std::count(text.begin(), text.end(), '\n'));
  status->SetDisplayPosition(10, std::max(240, size[1]) - 10 - lines * 19 - 8);
}

void ProbeView::add_plot_samples(const std::vector<PlotSample>& samples) {
  Impl& v = *impl_;
  for (const auto& s : samples) {
    if (!v.plot.empty() && s.t_s < v.plot.back().t_s) v.plot.clear();  // time went back: a reset
    v.plot.push_back(s);
  }
  while (!v.plot.empty() && v.plot.back().t_s - v.plot.front().t_s > v.setup.plot_window_s) v.plot.pop_front();
}

void ProbeView::clear_plot() { impl_->plot.clear(); }

void ProbeView::set_hud(const HudInfo& hud) { impl_->hud_info = hud; }

}  // namespace vx::probe
