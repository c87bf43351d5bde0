#pragma once
/// @file png_stats.h
/// What a test can tell of a PNG without looking at it: its size, how many pixels differ from
/// the background (the top-left pixel's colour), and the ink in a rectangle (pixels from the
/// top left, as an image viewer counts them). Reads with vtkPNGReader (tests link VTK).

#include <vtkImageData.h>
#include <vtkNew.h>
#include <vtkPNGReader.h>

#include <algorithm>
#include <array>
#include <cstdlib>
#include <filesystem>
#include <set>

namespace vx::testing {

struct PngStats {
  int width{0}, height{0};
  long long drawn{0};  ///< pixels that differ from the background
  int colours{0};      ///< distinct colours (a real picture has many: anti-aliased edges, text)
};

/// The RGB colour of pixel (x, y) counted from the top left.
inline std::array<int, 3> png_pixel(vtkImageData* img, int x, int y) {
  int dims[3];
  img->GetDimensions(dims);
  const auto* p = static_cast<const unsigned char*>(img->GetScalarPointer(x, dims[1] - 1 - y, 0));
  return {p[0], p[1], p[2]};
}

/// Size and drawn pixels of a PNG; all zero when it cannot be read.
inline PngStats png_stats(const std::filesystem::path& png) {
  PngStats s;
  if (!std::filesystem::is_regular_file(png)) return s;
  vtkNew<vtkPNGReader> r;
  if (!r->CanReadFile(png.string().c_str())) return s;
  r->SetFileName(png.string().c_str());
  r->Update();
  vtkImageData* img = r->GetOutput();
  int dims[3];
  img->GetDimensions(dims);
  if (img->GetNumberOfScalarComponents() < 3) return s;
  s.width = dims[0], s.height = dims[1];
  const auto bg = png_pixel(img, 0, 0);
  std::set<int> colours;
  for (int y = 0; y < s.height; ++y)
    for (int x = 0; x < s.width; ++x) {
      const auto c = png_pixel(img, x, y);
      if (c != bg) ++s.drawn;
      if (colours.size() < 100000) colours.insert((c[0] << 16) | (c[1] << 8) | c[2]);
    }
  s.colours = int(colours.size());
  return s;
}

/// Pixels in [x0, x1) x [y0, y1) (from the top left) darker than `level` in every channel: text and lines.
inline long long png_dark_pixels(const std::filesystem::path& png, int x0, int y0, int x1, int y1, int level = 128) {
  vtkNew<vtkPNGReader> r;
  r->SetFileName(png.string().c_str());
  r->Update();
  vtkImageData* img = r->GetOutput();
  int dims[3];
  img->GetDimensions(dims);
  long long n = 0;
  for (int y = std::max(0, y0); y < std::min(dims[1], y1); ++y)
    for (int x = std::max(0, x0); x < std::min(dims[0], x1); ++x) {
      const auto c = png_pixel(img, x, y);
      n += c[0] < level && c[1] < level && c[2] < level;
    }
  return n;
}

}  // namespace vx::testing
