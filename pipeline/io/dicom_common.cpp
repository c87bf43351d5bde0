#include "io/dicom_common.h"

#include <dcmtk/config/osconfig.h>
#include <dcmtk/dcmdata/dcdict.h>
#include <dcmtk/dcmdata/dcrledrg.h>
#include <dcmtk/dcmdata/dcrleerg.h>
#include <dcmtk/dcmjpeg/djdecode.h>
#include <dcmtk/dcmjpeg/djencode.h>
#include <dcmtk/dcmjpls/djdecode.h>
#include <dcmtk/dcmjpls/djencode.h>
#include <dcmtk/oflog/oflog.h>
#include <fmt/format.h>

#include <cmath>
#include <fstream>
#include <mutex>

#include "base/error.h"
#include "util/text.h"

namespace vx::dicom {

void init_dcmtk() {
  static std::once_flag once;
  std::call_once(once, [] {
    // header-only reads warn per file about values left on disk, and broken files log
    // errors that our own messages already carry (with the file name): keep the console readable
    OFLog::configure(OFLogger::FATAL_LOG_LEVEL);
    if (!dcmDataDict.isDictionaryLoaded())
      throw Error(
          "DICOM: the DCMTK data dictionary is not loaded, so no DICOM file can be read or "
          "written (expected /usr/share/libdcmtk17/dicom.dic; install the 'libdcmtk17' package "
          "or point DCMDICTPATH at a dicom.dic file)");
    // decoders for reading compressed series, encoders for writing test series
    DcmRLEDecoderRegistration::registerCodecs();
    DJDecoderRegistration::registerCodecs();
    DJLSDecoderRegistration::registerCodecs();
    DcmRLEEncoderRegistration::registerCodecs();
    DJEncoderRegistration::registerCodecs();
    DJLSEncoderRegistration::registerCodecs();
  });
}

std::string format_ds(double value) {
  if (!std::isfinite(value)) throw Error("DICOM: cannot write a non-finite number as a decimal string");
  if (std::abs(value) < 1e-12) return "0";
  for (int precision = 12; precision >= 1; --precision) {
    std::string s = fmt::format("{:.{}g}", value, precision);
    if (s.size() <= 16) return s;
  }
  throw Error(fmt::format("DICOM: the number {} does not fit a 16-character decimal string", value));
}

bool has_dicm_magic(const std::filesystem::path& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw Error("cannot open " + quoted(path) + " for reading (check its permissions)");
  char head[132] = {};
  in.read(head, sizeof head);
  return in.gcount() == std::streamsize(sizeof head) && std::string(head + 128, 4) == "DICM";
}

}  // namespace vx::dicom
