#pragma once
/// @file vti_check.h
/// Private to pipeline/io: the checks a .vti gets after vtkXMLImageDataReader has read its
/// XML header and before it reads any data (VTK 9.1's reader trusts the header: a reversed
/// extent, a block header of the wrong width or byte order crash it or make it allocate
/// terabytes). Extents must be in order and inside the whole extent; every point and cell data
/// array's block header (raw or base64, inline or appended, compressed or not) must describe
/// the bytes its extent needs and fit in the file.

#include <filesystem>

class vtkXMLImageDataReader;

namespace vx::volume_formats {

/// Throws vx::Error naming `path` and what is wrong; `reader` has run UpdateInformation().
void check_vti_before_reading(vtkXMLImageDataReader& reader, const std::filesystem::path& path);

}  // namespace vx::volume_formats
