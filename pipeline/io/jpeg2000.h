#pragma once
/// @file jpeg2000.h
/// Private to pipeline/io: JPEG 2000 in DICOM (transfer syntaxes 1.2.840.10008.1.2.4.90,
/// lossless only, and .91, lossless or lossy), which DCMTK 3.6.7 has no codec for. OpenJPEG
/// decodes the fragments DCMTK hands over (one codestream per frame, over one or more
/// fragments); it encodes too, so the writer can make test series in both syntaxes.
/// Registered once by dicom::init_dcmtk().

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

class DcmRepresentationParameter;

namespace vx::dicom {

/// Registers the two JPEG 2000 codecs with DCMTK's codec list (decoding and encoding).
void register_jpeg2000_codecs();

/// The representation parameter for writing JPEG 2000 with DCMTK's chooseRepresentation():
/// lossless (5/3 wavelet), or lossy at `compression_ratio`:1 (9/7 wavelet; transfer syntax
/// 1.2.840.10008.1.2.4.91 only).
[[nodiscard]] std::unique_ptr<DcmRepresentationParameter> jpeg2000_parameter(bool lossless,
                                                                             double compression_ratio = 8.0);

/// A decoded JPEG 2000 image: components interleaved, each value as the codestream gives it.
struct J2kImage {
  int width{0}, height{0}, components{0}, precision{0};
  bool is_signed{false};
  std::vector<std::int32_t> values;  ///< height x width x components, component fastest
};

/// Decodes one J2K codestream (or JP2 file) of `size` bytes; throws vx::Error with OpenJPEG's
/// message when it cannot. `max_values` bounds what the header may declare (width x height x
/// components) before anything is allocated for it.
[[nodiscard]] J2kImage decode_jpeg2000(const std::uint8_t* data, std::size_t size, std::size_t max_values);

/// Encodes one greyscale image (`width` x `height` values of `bits` bits, signed or not) as a
/// J2K codestream: reversible 5/3 wavelet when `lossless`, else the 9/7 wavelet at
/// `compression_ratio`:1. Throws vx::Error when OpenJPEG fails.
[[nodiscard]] std::vector<std::uint8_t> encode_jpeg2000(const std::int32_t* values, int width, int height, int bits,
                                                        bool is_signed, bool lossless, double compression_ratio = 8.0);

}  // namespace vx::dicom
