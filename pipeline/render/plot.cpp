// Plots rasterised on the CPU: a float RGB canvas, anti-aliased lines, markers and boxes
// (coverage from the distance to the shape), text by vtkFreeTypeTools (FreeType into a
// vtkImageData, no OpenGL, no display), written by vtkPNGWriter through write_atomically.
#include "render/plot.h"

#include <fmt/format.h>
#include <vtkFreeTypeTools.h>
#include <vtkImageData.h>
#include <vtkNew.h>
#include <vtkPNGWriter.h>
#include <vtkSmartPointer.h>
#include <vtkStdString.h>
#include <vtkTextProperty.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <mutex>
#include <utility>

#include "base/error.h"
#include "util/atomic_file.h"
#include "util/vtk_messages.h"

namespace vx {
namespace fs = std::filesystem;

namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

struct Rgb {
  float r{0}, g{0}, b{0};
};

int hex_digit(char c) {
  if (c >= '0' && c <= '9') return c - '0';
  if (c >= 'a' && c <= 'f') return c - 'a' + 10;
  if (c >= 'A' && c <= 'F') return c - 'A' + 10;
  return -1;
}

Rgb rgb8(int r, int g, int b) { return {float(r) / 255.f, float(g) / 255.f, float(b) / 255.f}; }

/// "#rrggbb" or one of a few names (those gnuplot users write); throws on anything else.
Rgb parse_color(const std::string& s) {
  if (s.size() == 7 && s[0] == '#') {
    int v[6];
    for (int i = 0; i < 6; ++i)
      if ((v[i] = hex_digit(s[std::size_t(i) + 1])) < 0) throw Error("plot: bad colour '" + s + "'");
    return rgb8(16 * v[0] + v[1], 16 * v[2] + v[3], 16 * v[4] + v[5]);
  }
  static const std::pair<const char*, Rgb> named[] = {
      {"black", rgb8(0, 0, 0)},           {"white", rgb8(255, 255, 255)},    {"red", rgb8(0xd6, 0x27, 0x28)},
      {"blue", rgb8(0x1f, 0x77, 0xb4)},   {"green", rgb8(0x2c, 0xa0, 0x2c)}, {"orange", rgb8(0xff, 0x7f, 0x0e)},
      {"purple", rgb8(0x94, 0x67, 0xbd)}, {"brown", rgb8(0x8c, 0x56, 0x4b)}, {"gray", rgb8(0x80, 0x80, 0x80)},
      {"grey", rgb8(0x80, 0x80, 0x80)}};
  for (const auto& [name, c] : named)
    if (s == name) return c;
  // grayNN / greyNN: NN percent of white
  if (s.size() > 4 && (s.rfind("gray", 0) == 0 || s.rfind("grey", 0) == 0) &&
      std::all_of(s.begin() + 4, s.end(), [](char c) { return c >= '0' && c <= '9'; })) {
    const float v = std::min(100, std::stoi(s.substr(4))) / 100.f;
    return {v, v, v};
  }
  throw Error("plot: unknown colour '" + s + "' (use \"#rrggbb\" or black, gray40, red, blue, green, orange, ...)");
}

/// The colour cycle of series without a colour (Tableau 10, distinct and print-safe).
Rgb cycle_color(int i) {
  static const char* cycle[] = {"#1f77b4", "#d62728", "#2ca02c", "#ff7f0e", "#9467bd",
                                "#8c564b", "#e377c2", "#17becf", "#7f7f7f", "#bcbd22"};
  return parse_color(cycle[i % 10]);
}

/// Viridis at t in [0, 1].
Rgb viridis(double t) {
  static const Rgb stops[] = {rgb8(0x44, 0x01, 0x54), rgb8(0x3b, 0x52, 0x8b), rgb8(0x21, 0x91, 0x8c),
                              rgb8(0x5e, 0xc9, 0x62), rgb8(0xfd, 0xe7, 0x25)};
  t = std::clamp(std::isfinite(t) ? t : 0.0, 0.0, 1.0) * 4.0;
  const int i = std::min(3, int(t));
  const float w = float(t - i);
  return {stops[i].r + w * (stops[i + 1].r - stops[i].r), stops[i].g + w * (stops[i + 1].g - stops[i].g),
          stops[i].b + w * (stops[i + 1].b - stops[i].b)};
}

/// A clip rectangle in pixels, [x0, x1) x [y0, y1).
struct Box {
  double x0{0}, y0{0}, x1{0}, y1{0};
};

class Canvas {
 public:
  Canvas(int w, int h) : w_(w), h_(h), px_(std::size_t(w) * std::size_t(h) * 3, 1.0f) {}
  [[nodiscard]] int width() const { return w_; }
  [[nodiscard]] int height() const { return h_; }

  void blend(int x, int y, Rgb c, float a) {
    if (x < 0 || y < 0 || x >= w_ || y >= h_ || a <= 0) return;
    a = std::min(a, 1.0f);
    float* p = &px_[3 * (std::size_t(y) * std::size_t(w_) + std::size_t(x))];
    p[0] += a * (c.r - p[0]);
    p[1] += a * (c.g - p[1]);
    p[2] += a * (c.b - p[2]);
  }

  /// A rectangle with anti-aliased edges (coverage = the pixel's overlap), clipped to `clip`.
  /// With `snap`, its edges go to whole pixels: boxes side by side leave no seam.
  void fill_rect(Box r, Rgb c, float alpha, Box clip, bool snap = false) {
    if (snap) r = {std::round(r.x0), std::round(r.y0), std::round(r.x1), std::round(r.y1)};
    r.x0 = std::max(r.x0, clip.x0), r.x1 = std::min(r.x1, clip.x1);
    r.y0 = std::max(r.y0, clip.y0), r.y1 = std::min(r.y1, clip.y1);
    if (!(r.x1 > r.x0 && r.y1 > r.y0)) return;
    for (int y = int(std::floor(r.y0)); y < int(std::ceil(r.y1)); ++y) {
      const double cy = std::min(r.y1, y + 1.0) - std::max(r.y0, double(y));
      for (int x = int(std::floor(r.x0)); x < int(std::ceil(r.x1)); ++x) {
        const double cx = std::min(r.x1, x + 1.0) - std::max(r.x0, double(x));
        blend(x, y, c, alpha * float(cx * cy));
      }
    }
  }

  /// A polyline `width` pixels wide with round joins and caps, dashed by `dash` (on, off, ...
  /// lengths in pixels; empty: solid), clipped to `clip`. Non-finite points break the line.
  void polyline(const std::vector<std::array<double, 2>>& pts, double width, Rgb c, const std::vector<double>& dash,
                Box clip) {
    const double hw = std::max(0.5, 0.5 * width);
    const float strength = float(std::min(1.0, width));
    begin_mask(clip);
    std::size_t di = 0;
    double left = dash.empty() ? 0 : dash[0];
    for (std::size_t i = 1; i < pts.size(); ++i) {
      const auto a = pts[i - 1], b = pts[i];
      if (!std::isfinite(a[0] + a[1] + b[0] + b[1])) continue;
      if (dash.empty()) {
        segment(a, b, hw);
        continue;
      }
      const double len = std::hypot(b[0] - a[0], b[1] - a[1]);
      double s = 0;
      while (s < len) {
        const double step = std::min(left, len - s);
        if (di % 2 == 0) {
          const double t0 = s / std::max(len, 1e-12), t1 = (s + step) / std::max(len, 1e-12);
          segment({a[0] + t0 * (b[0] - a[0]), a[1] + t0 * (b[1] - a[1])},
                  {a[0] + t1 * (b[0] - a[0]), a[1] + t1 * (b[1] - a[1])}, hw);
        }
        s += step;
        left -= step;
        if (left <= 1e-9) {
          di = (di + 1) % dash.size();
          left = dash[di];
          if (left <= 0 && di % 2 == 0) {  // a dot: a zero-length dash
            const double t = s / std::max(len, 1e-12);
            const std::array<double, 2> p{a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])};
            segment(p, p, hw);
            di = (di + 1) % dash.size();
            left = dash[di];
          }
        }
      }
    }
    end_mask(c, strength);
  }

  /// A marker of gnuplot-like `type` with radius `r` at (x, y).
  void marker(double x, double y, int type, double r, Rgb c, Box clip) {
    if (!std::isfinite(x) || !std::isfinite(y)) return;
    if (x < clip.x0 - r || x > clip.x1 + r || y < clip.y0 - r || y > clip.y1 + r) return;
    const double line = std::max(1.2, 0.28 * r);
    auto sd = [&](double px, double py) -> double {  // signed distance, < 0 inside
      const double ax = std::abs(px), ay = std::abs(py);
      switch (type) {
        case 1:  // plus
          return std::min(std::max(ax - r, ay - 0.5 * line), std::max(ay - r, ax - 0.5 * line));
        case 2: {  // cross
          const double u = std::abs(px + py) / std::sqrt(2.0), v = std::abs(px - py) / std::sqrt(2.0);
          return std::min(std::max(u - r, v - 0.5 * line), std::max(v - r, u - 0.5 * line));
        }
        case 4:  // open square
        case 5: {
          const double d = std::max(ax, ay) - 0.85 * r;
          return type == 5 ? d : std::abs(d) - 0.5 * line;
        }
        case 6:  // open circle
          return std::abs(std::hypot(px, py) - r) - 0.5 * line;
        case 8:  // open triangle
        case 9: {
          // pointing up (y grows downwards): the three edges' half planes
          const double k = 0.5, s = std::sqrt(3.0) / 2;
          const double d = std::max({py - 0.5 * r, s * px - k * py - 0.5 * r, -s * px - k * py - 0.5 * r}) * 1.15;
          return type == 9 ? d : std::abs(d) - 0.5 * line;
        }
        case 12:  // open diamond
        case 13: {
          const double d = (ax + ay - 1.15 * r) / std::sqrt(2.0);
          return type == 13 ? d : std::abs(d) - 0.5 * line;
        }
        default:  // 7 and the rest: a disc
          return std::hypot(px, py) - r;
      }
    };
    const int x0 = int(std::floor(x - r - 2)), x1 = int(std::ceil(x + r + 2));
    const int y0 = int(std::floor(y - r - 2)), y1 = int(std::ceil(y + r + 2));
    for (int py = y0; py <= y1; ++py)
      for (int px = x0; px <= x1; ++px)
        blend(px, py, c, float(std::clamp(0.5 - sd(px + 0.5 - x, py + 0.5 - y), 0.0, 1.0)));
  }

  /// The image, rows flipped to VTK's bottom-up order.
  [[nodiscard]] vtkSmartPointer<vtkImageData> image() const {
    auto img = vtkSmartPointer<vtkImageData>::New();
    img->SetDimensions(w_, h_, 1);
    img->AllocateScalars(VTK_UNSIGNED_CHAR, 3);
    auto* out = static_cast<unsigned char*>(img->GetScalarPointer());
    for (int y = 0; y < h_; ++y)
      for (int x = 0; x < w_; ++x)
        for (int k = 0; k < 3; ++k)
          out[3 * (std::size_t(h_ - 1 - y) * std::size_t(w_) + std::size_t(x)) + std::size_t(k)] =
              static_cast<unsigned char>(
                  std::lround(255.f * std::clamp(px_[3 * (std::size_t(y) * std::size_t(w_) + x) + k], 0.f, 1.f)));
    return img;
  }

 private:
  // a polyline's coverage, the maximum over its pieces (joins are not drawn twice)
  void begin_mask(Box clip) {
    mx0_ = std::max(0, int(std::floor(clip.x0))), my0_ = std::max(0, int(std::floor(clip.y0)));
    mx1_ = std::min(w_, int(std::ceil(clip.x1))), my1_ = std::min(h_, int(std::ceil(clip.y1)));
    mask_.assign(std::size_t(std::max(0, mx1_ - mx0_)) * std::size_t(std::max(0, my1_ - my0_)), 0.f);
    tx0_ = mx1_, ty0_ = my1_, tx1_ = mx0_, ty1_ = my0_;
  }
  void segment(std::array<double, 2> a, std::array<double, 2> b, double hw) {
    const int x0 = std::max(mx0_, int(std::floor(std::min(a[0], b[0]) - hw - 1)));
    const int x1 = std::min(mx1_ - 1, int(std::ceil(std::max(a[0], b[0]) + hw + 1)));
    const int y0 = std::max(my0_, int(std::floor(std::min(a[1], b[1]) - hw - 1)));
    const int y1 = std::min(my1_ - 1, int(std::ceil(std::max(a[1], b[1]) + hw + 1)));
    if (x0 > x1 || y0 > y1) return;
    tx0_ = std::min(tx0_, x0), tx1_ = std::max(tx1_, x1), ty0_ = std::min(ty0_, y0), ty1_ = std::max(ty1_, y1);
    const double dx = b[0] - a[0], dy = b[1] - a[1], l2 = dx * dx + dy * dy;
    const int mw = mx1_ - mx0_;
    for (int y = y0; y <= y1; ++y)
      for (int x = x0; x <= x1; ++x) {
        const double px = x + 0.5 - a[0], py = y + 0.5 - a[1];
        const double t = l2 > 0 ? std::clamp((px * dx + py * dy) / l2, 0.0, 1.0) : 0.0;
        const double d = std::hypot(px - t * dx, py - t * dy);
        const float cov = float(std::clamp(hw + 0.5 - d, 0.0, 1.0));
        float& m = mask_[std::size_t(y - my0_) * std::size_t(mw) + std::size_t(x - mx0_)];
        m = std::max(m, cov);
      }
  }
  void end_mask(Rgb c, float strength) {
    const int mw = mx1_ - mx0_;
    for (int y = ty0_; y <= ty1_; ++y)
      for (int x = tx0_; x <= tx1_; ++x)
        blend(x, y, c, strength * mask_[std::size_t(y - my0_) * std::size_t(mw) + std::size_t(x - mx0_)]);
  }

  int w_, h_;
  std::vector<float> px_;
  std::vector<float> mask_;
  int mx0_{0}, my0_{0}, mx1_{0}, my1_{0}, tx0_{0}, ty0_{0}, tx1_{0}, ty1_{0};
};

// --- text -----------------------------------------------------------------------------------

enum class HJust { left, center, right };
enum class VJust { bottom, center, top };

struct Font {
  double size{12};
  bool bold{false};
  double angle{0};  ///< degrees, counter-clockwise
};

vtkNew<vtkTextProperty> text_property(const Font& f, HJust h, VJust v) {
  vtkNew<vtkTextProperty> tp;
  tp->SetFontFamilyToArial();
  tp->SetFontSize(int(std::lround(f.size)));
  tp->SetBold(f.bold);
  tp->SetItalic(false);
  tp->SetShadow(false);
  tp->SetColor(0, 0, 0);
  tp->SetOpacity(1.0);
  tp->SetBackgroundOpacity(0.0);
  tp->SetOrientation(f.angle);
  tp->SetJustification(h == HJust::left ? VTK_TEXT_LEFT : h == HJust::center ? VTK_TEXT_CENTERED : VTK_TEXT_RIGHT);
  tp->SetVerticalJustification(v == VJust::bottom   ? VTK_TEXT_BOTTOM
                               : v == VJust::center ? VTK_TEXT_CENTERED
                                                    : VTK_TEXT_TOP);
  return tp;
}

/// A text in runs, plain and raised: superscripts as gnuplot's enhanced text writes them, `^c`
/// raises one character (`n^3`), `^{...}` a group (`depth^{1.5}`); a '^' with nothing after it,
/// or before an unclosed '{', is drawn as it is. (VTK's built-in fonts have no superscript
/// digits: a "¹" or "⁵" in the text is not drawn.)
struct TextRun {
  std::string text;
  bool raised{false};
};

std::vector<TextRun> text_runs(const std::string& s) {
  std::vector<TextRun> runs;
  std::string plain;
  const auto flush = [&] {
    if (!plain.empty()) runs.push_back({plain, false});
    plain.clear();
  };
  for (std::size_t i = 0; i < s.size(); ++i) {
    if (s[i] != '^' || i + 1 == s.size()) {
      plain += s[i];
      continue;
    }
    std::string up;
    if (s[i + 1] == '{') {
      const std::size_t close = s.find('}', i + 2);
      if (close == std::string::npos) {
        plain += s[i];
        continue;
      }
      up = s.substr(i + 2, close - i - 2);
      i = close;
    } else {
      // one character: a UTF-8 sequence whole
      const auto lead = static_cast<unsigned char>(s[i + 1]);
      const std::size_t n = lead >= 0xF0 ? 4 : lead >= 0xE0 ? 3 : lead >= 0xC0 ? 2 : 1;
      up = s.substr(i + 1, n);
      i += n;
    }
    flush();
    if (!up.empty()) runs.push_back({up, true});
  }
  flush();
  return runs;
}

bool has_raised_run(const std::vector<TextRun>& runs) {
  return std::any_of(runs.begin(), runs.end(), [](const TextRun& r) { return r.raised; });
}

/// The coverage of a text with raised runs, unrotated: `w` x `h` alphas, u to the right and v
/// up from the left end of the box's bottom (FreeType's bottom: the face's descent, the same for
/// every text of a size). A raised run is 0.7 times the size, its bottom 0.42 sizes up.
struct TextMask {
  int w{0}, h{0};
  std::vector<float> alpha;  ///< w x h, index v * w + u
};

TextMask text_mask(const std::vector<TextRun>& runs, const Font& f) {
  struct Piece {
    vtkSmartPointer<vtkImageData> img;
    int u{0}, v{0};
  };
  std::vector<Piece> pieces;
  vtkFreeTypeTools* ft = vtkFreeTypeTools::GetInstance();
  ft->ScaleToPowerTwoOff();
  TextMask m;
  for (const TextRun& r : runs) {
    const Font rf{r.raised ? std::max(6.0, std::round(0.7 * f.size)) : f.size, f.bold, 0};
    const auto tp = text_property(rf, HJust::left, VJust::bottom);
    auto img = vtkSmartPointer<vtkImageData>::New();
    if (!ft->RenderString(tp.GetPointer(), vtkStdString(r.text), 72, img.GetPointer()))
      throw Error("plot: FreeType cannot draw the text '" + r.text + "'");
    if (img->GetNumberOfScalarComponents() < 4) throw Error("plot: FreeType gave no alpha channel");
    int e[6];
    img->GetExtent(e);
    const int v = r.raised ? int(std::lround(0.42 * f.size)) : 0;
    pieces.push_back({img, m.w - e[0], v - e[2]});
    m.w += e[1] - e[0] + 1;  // the box's width is the run's advance, spaces included
    m.h = std::max(m.h, v + e[3] - e[2] + 1);
  }
  m.alpha.assign(std::size_t(m.w) * std::size_t(m.h), 0.f);
  for (const Piece& p : pieces) {
    int e[6];
    p.img->GetExtent(e);
    for (int j = e[2]; j <= e[3]; ++j)
      for (int i = e[0]; i <= e[1]; ++i) {
        const int u = p.u + i, v = p.v + j;
        if (u < 0 || v < 0 || u >= m.w || v >= m.h) continue;
        const auto* px = static_cast<const unsigned char*>(p.img->GetScalarPointer(i, j, 0));
        float& a = m.alpha[std::size_t(v) * std::size_t(m.w) + std::size_t(u)];
        a = std::max(a, float(px[3]) / 255.f);
      }
  }
  return m;
}

/// Width and height of a text in pixels (0, 0 for an empty one).
std::array<int, 2> text_size(const std::string& s, const Font& f) {
  if (s.empty()) return {0, 0};
  if (const auto runs = text_runs(s); has_raised_run(runs)) {
    const TextMask m = text_mask(runs, f);
    return std::abs(std::remainder(f.angle, 180.0)) > 45 ? std::array<int, 2>{m.h, m.w} : std::array<int, 2>{m.w, m.h};
  }
  int bbox[4] = {0, -1, 0, -1};
  const auto tp = text_property(f, HJust::left, VJust::bottom);
  if (!vtkFreeTypeTools::GetInstance()->GetBoundingBox(tp.GetPointer(), vtkStdString(s), 72, bbox))
    throw Error("plot: FreeType cannot measure the text '" + s + "'");
  return {bbox[1] - bbox[0] + 1, bbox[3] - bbox[2] + 1};
}

/// Draws a text with raised runs (text_mask), justified in its own frame and turned by a right
/// angle (0 or 90 degrees, the angles plots use) about its anchor (x, y).
void draw_text_runs(Canvas& cv, const std::vector<TextRun>& runs, double x, double y, const Font& f, Rgb c, HJust h,
                    VJust v) {
  const TextMask m = text_mask(runs, f);
  const int quarter = int(std::lround(f.angle / 90.0)) % 4;
  if (std::abs(f.angle - 90.0 * std::lround(f.angle / 90.0)) > 1e-9 || (quarter != 0 && quarter != 1))
    throw Error(fmt::format("plot: text with a superscript at {} degrees (0 or 90 only)", f.angle));
  const int du = h == HJust::left ? 0 : h == HJust::center ? -m.w / 2 : -m.w;
  const int dv = v == VJust::bottom ? 0 : v == VJust::center ? -m.h / 2 : -m.h;
  const int ax = int(std::lround(x)), ay = int(std::lround(y));
  for (int j = 0; j < m.h; ++j)
    for (int i = 0; i < m.w; ++i) {
      const float a = m.alpha[std::size_t(j) * std::size_t(m.w) + std::size_t(i)];
      if (a <= 0) continue;
      const int u = i + du, w = j + dv;  // in the text's frame, w up
      if (quarter == 0)
        cv.blend(ax + u, ay - w, c, a);
      else  // turned a quarter counter-clockwise: the text reads upwards
        cv.blend(ax - w, ay - u, c, a);
    }
}

/// Draws `s` with its anchor (by the justifications) at pixel (x, y) of the canvas (y down).
void draw_text(Canvas& cv, const std::string& s, double x, double y, const Font& f, Rgb c, HJust h = HJust::left,
               VJust v = VJust::bottom) {
  if (s.empty()) return;
  if (const auto runs = text_runs(s); has_raised_run(runs)) return draw_text_runs(cv, runs, x, y, f, c, h, v);
  const auto tp = text_property(f, h, v);
  vtkNew<vtkImageData> img;
  vtkFreeTypeTools* ft = vtkFreeTypeTools::GetInstance();
  ft->ScaleToPowerTwoOff();
  if (!ft->RenderString(tp.GetPointer(), vtkStdString(s), 72, img.GetPointer()))
    throw Error("plot: FreeType cannot draw the text '" + s + "'");
  int e[6];
  img->GetExtent(e);
  if (img->GetNumberOfScalarComponents() < 4) throw Error("plot: FreeType gave no alpha channel");
  const int ax = int(std::lround(x)), ay = int(std::lround(y));
  for (int j = e[2]; j <= e[3]; ++j)
    for (int i = e[0]; i <= e[1]; ++i) {
      const auto* p = static_cast<const unsigned char*>(img->GetScalarPointer(i, j, 0));
      if (p[3]) cv.blend(ax + i, ay - j, c, float(p[3]) / 255.f);
    }
}

// --- axes -----------------------------------------------------------------------------------

/// 1, 2 or 5 times a power of ten near `raw`.
double nice_step(double raw) {
  const double p = std::pow(10.0, std::floor(std::log10(raw)));
  const double m = raw / p;
  return (m < 1.5 ? 1.0 : m < 3.0 ? 2.0 : m < 7.0 ? 5.0 : 10.0) * p;
}

/// "[lo:hi]" with "*" for automatic; "" is all automatic.
std::array<double, 2> parse_range(const std::string& s) {
  std::array<double, 2> r{kNaN, kNaN};
  if (s.empty()) return r;
  const auto colon = s.find(':');
  if (s.front() != '[' || s.back() != ']' || colon == std::string::npos)
    throw Error("plot: a range is written \"[lo:hi]\", got '" + s + "'");
  const std::string parts[2] = {s.substr(1, colon - 1), s.substr(colon + 1, s.size() - colon - 2)};
  for (int k = 0; k < 2; ++k) {
    std::string t = parts[k];
    t.erase(std::remove(t.begin(), t.end(), ' '), t.end());
    if (t.empty() || t == "*") continue;
    try {
      std::size_t used = 0;
      r[std::size_t(k)] = std::stod(t, &used);
      if (used != t.size()) throw std::invalid_argument(t);
    } catch (const std::exception&) {
      throw Error("plot: a range is written \"[lo:hi]\" with numbers or *, got '" + s + "'");
    }
  }
  return r;
}

struct Axis {
  double lo{0}, hi{1};
  bool log{false};
  std::vector<double> ticks;  ///< labelled (and gridded)
  std::vector<double> minor;  ///< tick marks only
  [[nodiscard]] double t(double v) const { return log ? std::log10(v) : v; }
  [[nodiscard]] double frac(double v) const { return (t(v) - t(lo)) / (t(hi) - t(lo)); }
};

std::string tick_label(double v, const Axis& a) {
  if (a.log) {
    const int e = int(std::floor(std::log10(v) + 1e-9));
    if (e >= -3 && e <= 4) return fmt::format("{:g}", v);
    const double m = v / std::pow(10.0, e);
    return std::abs(m - 1) < 1e-6 ? fmt::format("1e{}", e) : fmt::format("{:g}e{}", std::round(m * 100) / 100, e);
  }
  const double step = a.ticks.size() > 1 ? a.ticks[1] - a.ticks[0] : std::max(std::abs(v), 1.0);
  if (std::abs(v) < 1e-9 * step) v = 0;
  if (step >= 1e5 || step < 1e-4) return fmt::format("{:g}", v);
  const int decimals = std::max(0, -int(std::floor(std::log10(step) + 1e-9)));
  return fmt::format("{:.{}f}", v, decimals);
}

/// Fills the ticks of an axis whose range is set; with `extend`, widens it to the ticks.
void make_ticks(Axis& a, int target, bool extend_lo, bool extend_hi) {
  a.ticks.clear();
  a.minor.clear();
  if (!a.log) {
    const double step = nice_step((a.hi - a.lo) / std::max(2, target));
    if (extend_lo) a.lo = std::floor(a.lo / step + 1e-9) * step;
    if (extend_hi) a.hi = std::ceil(a.hi / step - 1e-9) * step;
    for (double k = std::ceil(a.lo / step - 1e-9); k * step <= a.hi + 1e-9 * step; k += 1) a.ticks.push_back(k * step);
    return;
  }
  const int e0 = int(std::floor(std::log10(a.lo))), e1 = int(std::ceil(std::log10(a.hi)));
  const int decades = std::max(1, e1 - e0);
  const int every = std::max(1, (decades + target - 1) / std::max(1, target));
  const double span = std::log10(a.hi) - std::log10(a.lo);
  for (int e = e0; e <= e1; ++e)
    for (int m = 1; m <= 9; ++m) {
      const double v = m * std::pow(10.0, e);
      if (v < a.lo * (1 - 1e-9) || v > a.hi * (1 + 1e-9)) continue;
      const bool major = m == 1 ? (e - e0) % every == 0 : span < 1.1 ? true : span < 2.5 ? (m == 2 || m == 5) : false;
      (major ? a.ticks : a.minor).push_back(v);
    }
}

// --- one panel -------------------------------------------------------------------------------

struct Entry {
  std::string title;
  Rgb color;
  double width;
  std::vector<double> dash;
  bool line, marker;
  int point_type;
  double point_radius;
};

std::vector<double> dash_pattern(int type, double width) {
  const double s = std::max(width, 1.3);
  switch (type) {
    case 2: return {5.5 * s, 3.5 * s};
    case 3: return {0.0, 2.6 * s};
    case 4: return {5.5 * s, 2.5 * s, 0.0, 2.5 * s};
    default: return {};
  }
}

const Rgb kInk = rgb8(0x22, 0x22, 0x22);
const Rgb kFrame = rgb8(0x55, 0x55, 0x55);
const Rgb kGrid = rgb8(0xe4, 0xe4, 0xe4);
const Font kTitle{15.5, true}, kSubtitle{12.5, false}, kLabel{13.5, false}, kTick{12, false}, kKey{12, false};

void draw_panel(Canvas& cv, const PlotPanel& panel, int top, int height) {
  const int W = cv.width();
  const double pad = 12;
  // the data ranges
  auto usable = [](double v, bool log) { return std::isfinite(v) && (!log || v > 0); };
  double xlo = 1e300, xhi = -1e300, ylo = 1e300, yhi = -1e300;
  auto take = [&](double x, double y) {
    if (!usable(x, panel.log_x) || !usable(y, panel.log_y)) return;
    xlo = std::min(xlo, x), xhi = std::max(xhi, x), ylo = std::min(ylo, y), yhi = std::max(yhi, y);
  };
  for (const auto& s : panel.series)
    for (std::size_t i = 0; i < s.x.size() && i < s.y.size(); ++i) take(s.x[i], s.y[i]);
  for (const auto& r : panel.rects) take(r.x0, r.y0), take(r.x1, r.y1);
  for (const auto& l : panel.labels) take(l.x, l.y);
  const bool empty = !(xlo <= xhi);
  const auto xr = parse_range(panel.xrange), yr = parse_range(panel.yrange);
  Axis ax, ay;
  ax.log = panel.log_x, ay.log = panel.log_y;
  // markers at the data's ends would sit on the frame: a little room on the automatic sides
  const bool markers = std::any_of(panel.series.begin(), panel.series.end(),
                                   [](const PlotSeries& s) { return s.points || s.with_points; });
  auto settle = [markers](Axis& a, double lo, double hi, const std::array<double, 2>& fixed, bool none) {
    if (none) lo = a.log ? 1 : 0, hi = a.log ? 10 : 1;
    if (std::isfinite(fixed[0])) lo = fixed[0];
    if (std::isfinite(fixed[1])) hi = fixed[1];
    if (a.log) lo = lo > 0 ? lo : 1e-3, hi = hi > lo ? hi : lo * 10;
    if (!(hi > lo)) {
      const double d = lo == 0 ? 1.0 : 0.1 * std::abs(lo);
      lo -= d, hi += d;
    }
    if (markers && !a.log && !none) {
      const double pad = 0.04 * (hi - lo);
      if (!std::isfinite(fixed[0])) lo -= pad;
      if (!std::isfinite(fixed[1])) hi += pad;
    }
    if (a.log && !std::isfinite(fixed[0]) && !std::isfinite(fixed[1])) {
      const double f = std::max(1.08, std::pow(hi / lo, 0.04));
      lo /= f, hi *= f;
    }
    a.lo = lo, a.hi = hi;
  };
  settle(ax, xlo, xhi, xr, empty);
  settle(ay, ylo, yhi, yr, empty);

  // the legend's entries
  std::vector<Entry> entries;
  std::vector<Rgb> colors;
  int cycle = 0;
  for (const auto& s : panel.series) {
    colors.push_back(s.color.empty() ? cycle_color(cycle++) : parse_color(s.color));
    const double pr = s.points ? (s.point_type == 7 ? 3.4 : 4.5) : 4.0;
    if (!s.title.empty())
      entries.push_back({s.title, colors.back(), s.line_width, dash_pattern(s.dash_type, s.line_width), !s.points,
                         s.points || s.with_points, s.point_type, pr});
  }
  const double row_h = kKey.size * 1.5, sample_w = 34;
  double key_w = 0;
  for (const auto& e : entries) key_w = std::max(key_w, sample_w + 8 + text_size(e.title, kKey)[0]);
  key_w += 16;
  const bool below = panel.key.find("below") != std::string::npos;
  const bool outside = panel.key.find("outside") != std::string::npos;

  // the margins: titles above, tick labels and axis labels left and below
  double y = top + pad;
  if (!panel.title.empty()) {
    draw_text(cv, panel.title, W / 2.0, y, kTitle, kInk, HJust::center, VJust::top);
    y += kTitle.size * 1.45;
  }
  if (!panel.subtitle.empty()) {
    draw_text(cv, panel.subtitle, W / 2.0, y, kSubtitle, rgb8(0x44, 0x44, 0x44), HJust::center, VJust::top);
    y += kSubtitle.size * 1.45;
  }
  const double area_top = y + 6;
  const bool bar = !panel.color_bar.label.empty();
  Axis abar;
  abar.lo = panel.color_bar.lo,
  abar.hi = panel.color_bar.hi > panel.color_bar.lo ? panel.color_bar.hi : panel.color_bar.lo + 1;
  double right = pad + 6;
  if (bar) {
    make_ticks(abar, 6, false, false);
    double tw = 0;
    for (double t : abar.ticks) tw = std::max(tw, double(text_size(tick_label(t, abar), kTick)[0]));
    right += 18 + 6 + tw + 10 + kLabel.size * 1.3 + 6;
  }
  if (outside && !entries.empty()) right += key_w + 10;
  // legend below: rows of entries
  std::vector<std::vector<std::size_t>> rows;
  if (below && !entries.empty()) {
    double used = 0;
    const double avail = W - 2 * pad;
    rows.emplace_back();
    for (std::size_t i = 0; i < entries.size(); ++i) {
      const double w = sample_w + 8 + text_size(entries[i].title, kKey)[0] + 22;
      if (used + w > avail && !rows.back().empty()) rows.emplace_back(), used = 0;
      rows.back().push_back(i);
      used += w;
    }
  }
  const double below_h = rows.size() * row_h + (rows.empty() ? 0 : 8);
  const double tick_h = kTick.size * 1.25, label_h = panel.xlabel.empty() ? 0 : kLabel.size * 1.4;
  const double area_bottom = top + height - pad - below_h - label_h - tick_h - 10;
  // y ticks decide the left margin
  make_ticks(ay, std::max(3, int((area_bottom - area_top) / 55)), !ay.log && !std::isfinite(yr[0]) && !empty,
             !ay.log && !std::isfinite(yr[1]) && !empty);
  double ytw = 0;
  for (double t : ay.ticks) ytw = std::max(ytw, double(text_size(tick_label(t, ay), kTick)[0]));
  const double ylabel_w = panel.ylabel.empty() ? 0 : kLabel.size * 1.4;
  double x0 = pad + ylabel_w + ytw + 10, x1 = W - right;
  double y0 = area_top, y1 = area_bottom;
  make_ticks(ax, std::max(3, int((x1 - x0) / 95)), !ax.log && !std::isfinite(xr[0]) && !empty,
             !ax.log && !std::isfinite(xr[1]) && !empty);
  if (panel.equal_aspect) {  // shrink one side so a unit is as long on both axes
    const double ux = (ax.t(ax.hi) - ax.t(ax.lo)) / (x1 - x0), uy = (ay.t(ay.hi) - ay.t(ay.lo)) / (y1 - y0);
    if (ux > uy) {
      const double h = (ay.t(ay.hi) - ay.t(ay.lo)) / ux;
      y0 += 0.5 * (y1 - y0 - h), y1 = y0 + h;
    } else {
      const double w = (ax.t(ax.hi) - ax.t(ax.lo)) / uy;
      x0 += 0.5 * (x1 - x0 - w), x1 = x0 + w;
    }
  }
  x0 = std::round(x0), x1 = std::round(x1), y0 = std::round(y0), y1 = std::round(y1);
  const Box area{x0, y0, x1, y1};
  auto X = [&](double v) { return x0 + ax.frac(v) * (x1 - x0); };
  auto Y = [&](double v) { return y1 - ay.frac(v) * (y1 - y0); };
  const Box page{0, double(top), double(W), double(top + height)};

  // grid, under everything
  for (double t : ax.ticks) {
    const double px = std::floor(X(t)) + 0.5;
    cv.polyline({{px, y0}, {px, y1}}, 1.0, kGrid, {}, area);
  }
  for (double t : ay.ticks) {
    const double py = std::floor(Y(t)) + 0.5;
    cv.polyline({{x0, py}, {x1, py}}, 1.0, kGrid, {}, area);
  }
  // boxes
  for (const auto& r : panel.rects) {
    const Rgb c =
        !r.color.empty() ? parse_color(r.color) : viridis((r.value - abar.lo) / std::max(1e-300, abar.hi - abar.lo));
    if (r.color.empty() && !std::isfinite(r.value)) continue;
    cv.fill_rect({std::min(X(r.x0), X(r.x1)), std::min(Y(r.y0), Y(r.y1)), std::max(X(r.x0), X(r.x1)),
                  std::max(Y(r.y0), Y(r.y1))},
                 c, 1.0f, area, true);
  }
  // the series; `ink` keeps where they went (every few pixels) for the legend's place
  std::vector<std::array<double, 2>> ink;
  for (std::size_t k = 0; k < panel.series.size(); ++k) {
    const auto& s = panel.series[k];
    std::vector<std::array<double, 2>> pts;
    for (std::size_t i = 0; i < s.x.size() && i < s.y.size(); ++i)
      pts.push_back(usable(s.x[i], panel.log_x) && usable(s.y[i], panel.log_y)
                        ? std::array<double, 2>{X(s.x[i]), Y(s.y[i])}
                        : std::array<double, 2>{kNaN, kNaN});
    for (std::size_t i = 0; i < pts.size(); ++i) {
      ink.push_back(pts[i]);
      if (i == 0 || s.points) continue;
      const double len = std::hypot(pts[i][0] - pts[i - 1][0], pts[i][1] - pts[i - 1][1]);
      for (int j = 1; std::isfinite(len) && j < std::min(2000.0, len / 4.0); ++j) {
        const double t = 4.0 * j / len;
        ink.push_back(
            {pts[i - 1][0] + t * (pts[i][0] - pts[i - 1][0]), pts[i - 1][1] + t * (pts[i][1] - pts[i - 1][1])});
      }
    }
    if (!s.points) cv.polyline(pts, s.line_width, colors[k], dash_pattern(s.dash_type, s.line_width), area);
    if (s.points || s.with_points) {
      const double r = s.points ? (s.point_type == 7 ? 3.4 : 4.5) : 4.0;
      for (const auto& p : pts) cv.marker(p[0], p[1], s.point_type, r, colors[k], area);
    }
  }
  for (const auto& l : panel.labels) {
    const Rgb c = parse_color(l.color);
    const double px = X(l.x), py = Y(l.y);
    if (l.marker) cv.marker(px, py, 2, 8, c, area);
    draw_text(cv, l.text, px + (l.marker ? 12 : 0), py - (l.marker ? 10 : 0), kKey, c,
              l.marker ? HJust::left : HJust::center, VJust::bottom);
  }
  if (empty)
    draw_text(cv, "no data", 0.5 * (x0 + x1), 0.5 * (y0 + y1), kLabel, rgb8(0x88, 0x88, 0x88), HJust::center,
              VJust::center);
  // frame, ticks, tick labels
  cv.polyline(
      {{x0 + 0.5, y0 + 0.5}, {x1 - 0.5, y0 + 0.5}, {x1 - 0.5, y1 - 0.5}, {x0 + 0.5, y1 - 0.5}, {x0 + 0.5, y0 + 0.5}},
      1.0, kFrame, {}, page);
  for (double t : ax.ticks) {
    const double px = std::floor(X(t)) + 0.5;
    cv.polyline({{px, y1}, {px, y1 + 5}}, 1.0, kFrame, {}, page);
    draw_text(cv, tick_label(t, ax), px, y1 + 7, kTick, kInk, HJust::center, VJust::top);
  }
  for (double t : ax.minor) {
    const double px = std::floor(X(t)) + 0.5;
    cv.polyline({{px, y1}, {px, y1 + 3}}, 1.0, kFrame, {}, page);
  }
  for (double t : ay.ticks) {
    const double py = std::floor(Y(t)) + 0.5;
    cv.polyline({{x0 - 5, py}, {x0, py}}, 1.0, kFrame, {}, page);
    draw_text(cv, tick_label(t, ay), x0 - 8, py, kTick, kInk, HJust::right, VJust::center);
  }
  for (double t : ay.minor) {
    const double py = std::floor(Y(t)) + 0.5;
    cv.polyline({{x0 - 3, py}, {x0, py}}, 1.0, kFrame, {}, page);
  }
  // axis labels
  draw_text(cv, panel.xlabel, 0.5 * (x0 + x1), y1 + 7 + tick_h + 4, kLabel, kInk, HJust::center, VJust::top);
  if (!panel.ylabel.empty())
    draw_text(cv, panel.ylabel, pad, 0.5 * (y0 + y1), Font{kLabel.size, false, 90}, kInk, HJust::center, VJust::top);
  // the colour bar
  if (bar) {
    const double bx0 = x1 + 16, bx1 = bx0 + 18;
    for (int py = int(y0); py < int(y1); ++py)
      cv.fill_rect({bx0, double(py), bx1, py + 1.0}, viridis((y1 - py - 0.5) / (y1 - y0)), 1.0f, page);
    cv.polyline({{bx0 + 0.5, y0 + 0.5},
                 {bx1 - 0.5, y0 + 0.5},
                 {bx1 - 0.5, y1 - 0.5},
                 {bx0 + 0.5, y1 - 0.5},
                 {bx0 + 0.5, y0 + 0.5}},
                1.0, kFrame, {}, page);
    double tw = 0;
    for (double t : abar.ticks) {
      const double py = std::floor(y1 - abar.frac(t) * (y1 - y0)) + 0.5;
      cv.polyline({{bx1, py}, {bx1 + 4, py}}, 1.0, kFrame, {}, page);
      const std::string s = tick_label(t, abar);
      tw = std::max(tw, double(text_size(s, kTick)[0]));
      draw_text(cv, s, bx1 + 7, py, kTick, kInk, HJust::left, VJust::center);
    }
    draw_text(cv, panel.color_bar.label, bx1 + 7 + tw + 10, 0.5 * (y0 + y1), Font{kLabel.size, false, 90}, kInk,
              HJust::center, VJust::top);
  }
  // the legend
  auto draw_entry = [&](const Entry& e, double ex, double ey) {  // (ex, ey): the row's left, middle
    if (e.line)
      cv.polyline({{ex, ey}, {ex + sample_w, ey}}, std::min(e.width, 3.0), e.color, e.dash,
                  {ex - 2, ey - 10, ex + sample_w + 2, ey + 10});
    if (e.marker) cv.marker(ex + 0.5 * sample_w, ey, e.point_type, e.point_radius, e.color, page);
    draw_text(cv, e.title, ex + sample_w + 8, ey, kKey, kInk, HJust::left, VJust::center);
  };
  if (!entries.empty() && below) {
    double ry = top + height - pad - below_h + 8 + 0.5 * row_h;
    for (const auto& row : rows) {
      double rw = 0;
      for (std::size_t i : row) rw += sample_w + 8 + text_size(entries[i].title, kKey)[0] + 22;
      double ex = 0.5 * (W - rw + 22);
      for (std::size_t i : row) {
        draw_entry(entries[i], ex, ry);
        ex += sample_w + 8 + text_size(entries[i].title, kKey)[0] + 22;
      }
      ry += row_h;
    }
  } else if (!entries.empty()) {
    const double kh = entries.size() * row_h + 10;
    double kx, ky;
    if (outside) {
      kx = W - pad - key_w - (bar ? 0 : 0);
      ky = y0;
    } else {
      bool r = panel.key.find("right") != std::string::npos;
      bool b = panel.key.find("bottom") != std::string::npos;
      if (panel.key == "best") {  // the inside corner over the fewest samples of the curves
        std::size_t fewest = ~std::size_t(0);
        for (int corner = 0; corner < 4; ++corner) {
          const bool cr = corner == 1 || corner == 3, cb = corner >= 2;
          const double bx = cr ? x1 - 10 - key_w : x0 + 10, by = cb ? y1 - 10 - kh : y0 + 10;
          const auto under = std::size_t(std::count_if(ink.begin(), ink.end(), [&](const std::array<double, 2>& q) {
            return q[0] >= bx - 6 && q[0] <= bx + key_w + 6 && q[1] >= by - 6 && q[1] <= by + kh + 6;
          }));
          if (under < fewest) fewest = under, r = cr, b = cb;
        }
      }
      kx = r ? x1 - 10 - key_w : x0 + 10;
      ky = b ? y1 - 10 - kh : y0 + 10;
    }
    const Box kb{kx, ky, kx + key_w, ky + kh};
    cv.fill_rect(kb, rgb8(255, 255, 255), 0.88f, page);
    cv.polyline({{kx + 0.5, ky + 0.5},
                 {kx + key_w - 0.5, ky + 0.5},
                 {kx + key_w - 0.5, ky + kh - 0.5},
                 {kx + 0.5, ky + kh - 0.5},
                 {kx + 0.5, ky + 0.5}},
                1.0, rgb8(0xc8, 0xc8, 0xc8), {}, page);
    for (std::size_t i = 0; i < entries.size(); ++i) draw_entry(entries[i], kx + 8, ky + 5 + (i + 0.5) * row_h);
  }
}

/// FreeType's singleton and VTK's message window are shared: one plot at a time.
std::mutex& plot_mutex() {
  static std::mutex m;
  return m;
}

}  // namespace

void check_plot_color(const std::string& color) { (void)parse_color(color); }

std::vector<double> plot_ticks(double lo, double hi, bool log, int target) {
  Axis a;
  a.lo = lo, a.hi = hi, a.log = log;
  make_ticks(a, target, false, false);
  return a.ticks;
}

void plot_png(const std::vector<PlotPanel>& panels, const fs::path& png, int width, int panel_height) {
  if (panels.empty()) throw Error("plot: nothing to draw");
  if (width < 200 || panel_height < 150 || width > 10000 || panel_height > 10000)
    throw Error(fmt::format("plot: a picture of {} x {} pixels per panel is outside 200..10000 x 150..10000", width,
                            panel_height));
  std::lock_guard<std::mutex> lock(plot_mutex());
  Canvas cv(width, panel_height * int(panels.size()));
  for (std::size_t i = 0; i < panels.size(); ++i) draw_panel(cv, panels[i], int(i) * panel_height, panel_height);
  const auto img = cv.image();
  const VtkMessageCapture vtk_messages;
  write_atomically(png, [&](const fs::path& tmp) {
    vtkNew<vtkPNGWriter> writer;
    writer->SetInputData(img);
    writer->SetFileName(tmp.string().c_str());
    writer->Write();
    if (!vtk_messages.errors().empty())
      throw Error("plot: VTK could not write the PNG " + png.string() + ": " + vtk_messages.errors().front());
  });
}

}  // namespace vx
