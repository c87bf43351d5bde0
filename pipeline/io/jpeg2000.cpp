// JPEG 2000 in DICOM through OpenJPEG: a DCMTK codec (dccodec.h) per transfer syntax that
// decodes the fragments of a frame and encodes uncompressed frames, plus the memory streams
// OpenJPEG reads and writes through.
#include "io/jpeg2000.h"

#include <dcmtk/config/osconfig.h>
#include <dcmtk/dcmdata/dccodec.h>
#include <dcmtk/dcmdata/dcdeftag.h>
#include <dcmtk/dcmdata/dcerror.h>
#include <dcmtk/dcmdata/dcitem.h>
#include <dcmtk/dcmdata/dcpixel.h>
#include <dcmtk/dcmdata/dcpixseq.h>
#include <dcmtk/dcmdata/dcpxitem.h>
#include <dcmtk/dcmdata/dcstack.h>
#include <dcmtk/dcmdata/dcvrobow.h>
#include <dcmtk/dcmdata/dcxfer.h>
#include <fmt/format.h>
#include <openjpeg.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <memory>
#include <mutex>

#include "base/error.h"

namespace vx::dicom {
namespace {

// ---------------------------------------------------------------------------------------
// OpenJPEG's streams over memory

struct MemoryIn {
  const std::uint8_t* data;
  std::size_t size;
  std::size_t pos{0};
};

OPJ_SIZE_T read_in(void* buffer, OPJ_SIZE_T n, void* user) {
  auto* m = static_cast<MemoryIn*>(user);
  if (m->pos >= m->size) return OPJ_SIZE_T(-1);
  const std::size_t k = std::min<std::size_t>(n, m->size - m->pos);
  std::memcpy(buffer, m->data + m->pos, k);
  m->pos += k;
  return k;
}
OPJ_OFF_T skip_in(OPJ_OFF_T n, void* user) {
  auto* m = static_cast<MemoryIn*>(user);
  if (n < 0 ? std::size_t(-n) > m->pos : std::size_t(n) > m->size - m->pos) return -1;
  m->pos = std::size_t(OPJ_OFF_T(m->pos) + n);
  return n;
}
OPJ_BOOL seek_in(OPJ_OFF_T to, void* user) {
  auto* m = static_cast<MemoryIn*>(user);
  if (to < 0 || std::size_t(to) > m->size) return OPJ_FALSE;
  m->pos = std::size_t(to);
  return OPJ_TRUE;
}

struct MemoryOut {
  std::vector<std::uint8_t> data;
  std::size_t pos{0};
};

OPJ_SIZE_T write_out(void* buffer, OPJ_SIZE_T n, void* user) {
  auto* m = static_cast<MemoryOut*>(user);
  if (m->pos + n > m->data.size()) m->data.resize(m->pos + n);
  std::memcpy(m->data.data() + m->pos, buffer, n);
  m->pos += n;
  return n;
}
OPJ_OFF_T skip_out(OPJ_OFF_T n, void* user) {
  auto* m = static_cast<MemoryOut*>(user);
  if (n < 0 && std::size_t(-n) > m->pos) return -1;
  m->pos = std::size_t(OPJ_OFF_T(m->pos) + n);
  if (m->pos > m->data.size()) m->data.resize(m->pos);
  return n;
}
OPJ_BOOL seek_out(OPJ_OFF_T to, void* user) {
  auto* m = static_cast<MemoryOut*>(user);
  if (to < 0) return OPJ_FALSE;
  m->pos = std::size_t(to);
  if (m->pos > m->data.size()) m->data.resize(m->pos);
  return OPJ_TRUE;
}

/// OpenJPEG's messages, kept for the error text (it prints nothing itself then).
struct Messages {
  std::string errors;
};
void on_error(const char* msg, void* user) {
  auto* m = static_cast<Messages*>(user);
  if (m->errors.size() < 400) m->errors += (m->errors.empty() ? "" : "; ") + std::string(msg ? msg : "");
  while (!m->errors.empty() && (m->errors.back() == '\n' || m->errors.back() == ' ')) m->errors.pop_back();
}
void on_quiet(const char*, void*) {}

struct CodecDeleter {
  void operator()(opj_codec_t* c) const { opj_destroy_codec(c); }
};
struct StreamDeleter {
  void operator()(opj_stream_t* s) const { opj_stream_destroy(s); }
};
struct ImageDeleter {
  void operator()(opj_image_t* i) const { opj_image_destroy(i); }
};

}  // namespace

J2kImage decode_jpeg2000(const std::uint8_t* data, std::size_t size, std::size_t max_values) {
  if (size < 12) throw Error("JPEG 2000: the codestream is empty or cut short");
  // a raw codestream starts with SOC (FF 4F); a JP2 file with its signature box
  static const std::uint8_t jp2[12] = {0, 0, 0, 0x0C, 0x6A, 0x50, 0x20, 0x20, 0x0D, 0x0A, 0x87, 0x0A};
  const bool is_jp2 = std::memcmp(data, jp2, 12) == 0;
  if (!is_jp2 && !(data[0] == 0xFF && data[1] == 0x4F))
    throw Error("JPEG 2000: the fragment is not a J2K codestream (no SOC marker FF4F)");
  std::unique_ptr<opj_codec_t, CodecDeleter> codec(opj_create_decompress(is_jp2 ? OPJ_CODEC_JP2 : OPJ_CODEC_J2K));
  Messages messages;
  opj_set_error_handler(codec.get(), on_error, &messages);
  opj_set_warning_handler(codec.get(), on_quiet, nullptr);
  opj_set_info_handler(codec.get(), on_quiet, nullptr);
  opj_dparameters_t params;
  opj_set_default_decoder_parameters(&params);
  if (!opj_setup_decoder(codec.get(), &params)) throw Error("JPEG 2000: cannot set up the decoder");
  opj_decoder_set_strict_mode(codec.get(), OPJ_TRUE);  // a cut-short codestream is an error, not a blur
  MemoryIn in{data, size};
  std::unique_ptr<opj_stream_t, StreamDeleter> stream(opj_stream_create(1 << 16, OPJ_TRUE));
  opj_stream_set_user_data(stream.get(), &in, nullptr);
  opj_stream_set_user_data_length(stream.get(), size);
  opj_stream_set_read_function(stream.get(), read_in);
  opj_stream_set_skip_function(stream.get(), skip_in);
  opj_stream_set_seek_function(stream.get(), seek_in);
  opj_image_t* raw = nullptr;
  if (!opj_read_header(stream.get(), codec.get(), &raw))
    throw Error("JPEG 2000: cannot read the codestream header (" + messages.errors + ")");
  std::unique_ptr<opj_image_t, ImageDeleter> image(raw);
  // what the header declares, checked before OpenJPEG allocates for it
  if (image->numcomps < 1 || image->numcomps > 4 || image->x1 <= image->x0 || image->y1 <= image->y0)
    throw Error("JPEG 2000: the codestream header declares an empty image or an odd number of components");
  const double declared = double(image->x1 - image->x0) * double(image->y1 - image->y0) * double(image->numcomps);
  if (declared > double(max_values))
    throw Error(fmt::format("JPEG 2000: the codestream declares {} x {} x {} values, more than the image holds",
                            image->x1 - image->x0, image->y1 - image->y0, image->numcomps));
  if (!opj_decode(codec.get(), stream.get(), image.get()) || !opj_end_decompress(codec.get(), stream.get()))
    throw Error("JPEG 2000: the codestream does not decode (" + messages.errors + ")");
  J2kImage out;
  const opj_image_comp_t& c0 = image->comps[0];
  out.width = int(c0.w);
  out.height = int(c0.h);
  out.components = int(image->numcomps);
  out.precision = int(c0.prec);
  out.is_signed = c0.sgnd != 0;
  for (OPJ_UINT32 c = 0; c < image->numcomps; ++c) {
    const opj_image_comp_t& ci = image->comps[c];
    if (!ci.data || ci.w != c0.w || ci.h != c0.h || ci.dx != 1 || ci.dy != 1)
      throw Error("JPEG 2000: components of different sizes (subsampled colour) are not supported");
  }
  const std::size_t n = std::size_t(out.width) * std::size_t(out.height);
  out.values.resize(n * std::size_t(out.components));
  for (int c = 0; c < out.components; ++c)
    for (std::size_t p = 0; p < n; ++p)
      out.values[p * std::size_t(out.components) + std::size_t(c)] = image->comps[c].data[p];
  return out;
}

std::vector<std::uint8_t> encode_jpeg2000(const std::int32_t* values, int width, int height, int bits, bool is_signed,
                                          bool lossless, double compression_ratio) {
  opj_image_cmptparm_t cp{};
  cp.dx = cp.dy = 1;
  cp.w = OPJ_UINT32(width);
  cp.h = OPJ_UINT32(height);
  cp.prec = OPJ_UINT32(bits);
  cp.sgnd = is_signed ? 1 : 0;
  std::unique_ptr<opj_image_t, ImageDeleter> image(opj_image_create(1, &cp, OPJ_CLRSPC_GRAY));
  if (!image) throw Error("JPEG 2000: cannot create the image to encode");
  image->x0 = image->y0 = 0;
  image->x1 = OPJ_UINT32(width);
  image->y1 = OPJ_UINT32(height);
  std::copy(values, values + std::size_t(width) * std::size_t(height), image->comps[0].data);
  opj_cparameters_t params;
  opj_set_default_encoder_parameters(&params);
  params.tcp_numlayers = 1;
  params.cp_disto_alloc = 1;
  params.irreversible = lossless ? 0 : 1;
  params.tcp_rates[0] = lossless ? 0.0f : float(compression_ratio);
  params.numresolution = std::max(1, std::min(6, int(std::floor(std::log2(std::max(1, std::min(width, height))))) + 1));
  std::unique_ptr<opj_codec_t, CodecDeleter> codec(opj_create_compress(OPJ_CODEC_J2K));
  Messages messages;
  opj_set_error_handler(codec.get(), on_error, &messages);
  opj_set_warning_handler(codec.get(), on_quiet, nullptr);
  opj_set_info_handler(codec.get(), on_quiet, nullptr);
  if (!opj_setup_encoder(codec.get(), &params, image.get()))
    throw Error("JPEG 2000: cannot set up the encoder (" + messages.errors + ")");
  MemoryOut out;
  std::unique_ptr<opj_stream_t, StreamDeleter> stream(opj_stream_create(1 << 16, OPJ_FALSE));
  opj_stream_set_user_data(stream.get(), &out, nullptr);
  opj_stream_set_write_function(stream.get(), write_out);
  opj_stream_set_skip_function(stream.get(), skip_out);
  opj_stream_set_seek_function(stream.get(), seek_out);
  if (!opj_start_compress(codec.get(), image.get(), stream.get()) || !opj_encode(codec.get(), stream.get()) ||
      !opj_end_compress(codec.get(), stream.get()))
    throw Error("JPEG 2000: encoding failed (" + messages.errors + ")");
  return std::move(out.data);
}

namespace {

// ---------------------------------------------------------------------------------------
// the DCMTK codec

/// How a JPEG 2000 frame is encoded (the representation parameter).
class J2kParameter : public DcmRepresentationParameter {
 public:
  explicit J2kParameter(bool lossless = true, double ratio = 8.0) : lossless_(lossless), ratio_(ratio) {}
  DcmRepresentationParameter* clone() const override { return new J2kParameter(*this); }
  const char* className() const override { return "vx::J2kParameter"; }
  OFBool operator==(const DcmRepresentationParameter& arg) const override {
    const auto* o = dynamic_cast<const J2kParameter*>(&arg);
    return o && o->lossless_ == lossless_ && o->ratio_ == ratio_;
  }
  bool lossless() const { return lossless_; }
  double ratio() const { return ratio_; }

 private:
  bool lossless_;
  double ratio_;
};

class J2kCodecParameter : public DcmCodecParameter {
 public:
  DcmCodecParameter* clone() const override { return new J2kCodecParameter(*this); }
  const char* className() const override { return "vx::J2kCodecParameter"; }
};

/// The image pixel module of the data set a pixel element sits in.
struct PixelModule {
  long rows{0}, cols{0}, samples{1}, bits_allocated{0}, bits_stored{0}, pixel_rep{0}, frames{1};
  std::string photometric;
};

bool get_long(DcmItem* item, const DcmTagKey& tag, long& out) {
  Uint16 u = 0;
  if (item->findAndGetUint16(tag, u).good()) return out = u, true;
  Sint32 s = 0;
  if (item->findAndGetSint32(tag, s).good()) return out = s, true;
  return false;
}

OFCondition pixel_module(DcmItem* ds, PixelModule& m) {
  if (!ds || !get_long(ds, DCM_Rows, m.rows) || !get_long(ds, DCM_Columns, m.cols) ||
      !get_long(ds, DCM_BitsAllocated, m.bits_allocated))
    return EC_MissingAttribute;
  if (!get_long(ds, DCM_SamplesPerPixel, m.samples)) m.samples = 1;
  if (!get_long(ds, DCM_BitsStored, m.bits_stored)) m.bits_stored = m.bits_allocated;
  if (!get_long(ds, DCM_PixelRepresentation, m.pixel_rep)) m.pixel_rep = 0;
  if (!get_long(ds, DCM_NumberOfFrames, m.frames) || m.frames < 1) m.frames = 1;
  OFString pi;
  if (ds->findAndGetOFString(DCM_PhotometricInterpretation, pi).good()) m.photometric = pi.c_str();
  if (m.rows < 1 || m.cols < 1 || m.samples < 1 || m.samples > 4 ||
      (m.bits_allocated != 8 && m.bits_allocated != 16 && m.bits_allocated != 32))
    return EC_InvalidValue;
  return EC_Normal;
}

/// The data set that holds the pixel element on top of `stack`.
DcmItem* dataset_of(const DcmStack& stack) {
  DcmStack s(stack);
  if (s.card() > 0) (void)s.pop();
  while (s.card() > 0) {
    DcmObject* top = s.top();
    if (top && (top->ident() == EVR_dataset || top->ident() == EVR_item)) return static_cast<DcmItem*>(top);
    (void)s.pop();
  }
  return nullptr;
}

class J2kCodec : public DcmCodec {
 public:
  explicit J2kCodec(E_TransferSyntax xfer) : xfer_(xfer) {}

  OFCondition decode(const DcmRepresentationParameter* from, DcmPixelSequence* seq, DcmPolymorphOBOW& out,
                     const DcmCodecParameter* cp, const DcmStack& stack, OFBool& remove_old) const override {
    DcmItem* ds = dataset_of(stack);
    PixelModule m;
    if (OFCondition c = pixel_module(ds, m); c.bad()) return c;
    const double frame_bytes = double(m.rows) * double(m.cols) * double(m.samples) * double(m.bits_allocated / 8);
    const double total = frame_bytes * double(m.frames);
    if (total > 4.0e9) return EC_MemoryExhausted;
    Uint16* words = nullptr;
    if (out.createUint16Array(Uint32((std::uint64_t(total) + 1) / 2), words).bad() || !words) return EC_MemoryExhausted;
    Uint32 start = 0;
    OFString model;
    for (long f = 0; f < m.frames; ++f) {
      OFCondition c = decodeFrame(from, seq, cp, ds, Uint32(f), start,
                                  reinterpret_cast<Uint8*>(words) + std::size_t(frame_bytes) * std::size_t(f),
                                  Uint32(frame_bytes), model);
      if (c.bad()) return c;
    }
    if (m.samples == 3) {
      ds->putAndInsertString(DCM_PhotometricInterpretation, model.c_str());
      ds->putAndInsertUint16(DCM_PlanarConfiguration, 0);
    }
    remove_old = OFFalse;
    return EC_Normal;
  }

  OFCondition decodeFrame(const DcmRepresentationParameter*, DcmPixelSequence* seq, const DcmCodecParameter*,
                          DcmItem* ds, Uint32 frame, Uint32& start, void* buffer, Uint32 buffer_size,
                          OFString& model) const override {
    PixelModule m;
    if (OFCondition c = pixel_module(ds, m); c.bad()) return c;
    if (!seq || frame >= Uint32(m.frames)) return EC_IllegalParameter;
    const Uint32 fragments = Uint32(seq->card());
    if (fragments < 2) return EC_CorruptedData;
    // where the frame starts: the caller's running index, else DCMTK's offset-table logic
    if (start == 0 || start >= fragments) {
      if (m.frames == 1 || frame == 0) start = 1;
      else if (DcmCodec::determineStartFragment(frame, Sint32(m.frames), seq, start).bad()) return EC_CorruptedData;
    }
    // its codestream: one fragment per frame when they match, else fragments up to the EOC
    // marker (FF D9), else (one frame) all of them
    std::vector<std::uint8_t> code;
    Uint32 k = start;
    for (; k < fragments; ++k) {
      DcmPixelItem* item = nullptr;
      Uint8* bytes = nullptr;
      if (seq->getItem(item, k).bad() || !item || item->getUint8Array(bytes).bad()) return EC_CorruptedData;
      const Uint32 len = item->getLength();
      if (bytes && len) code.insert(code.end(), bytes, bytes + len);
      if (m.frames == 1) continue;
      if (Uint32(m.frames) + 1 == fragments) break;
      std::size_t end = code.size();
      while (end > 0 && code[end - 1] == 0) --end;  // fragments are padded to even length
      if (end >= 2 && code[end - 2] == 0xFF && code[end - 1] == 0xD9) break;
    }
    start = k + 1;
    const std::size_t pixels = std::size_t(m.rows) * std::size_t(m.cols);
    J2kImage image;
    try {
      image = decode_jpeg2000(code.data(), code.size(), pixels * std::size_t(m.samples));
    } catch (const Error&) {
      return EC_CorruptedData;
    }
    if (image.width != m.cols || image.height != m.rows || image.components != m.samples) return EC_CorruptedData;
    const std::size_t bytes = std::size_t(m.bits_allocated / 8);
    if (std::size_t(buffer_size) < pixels * std::size_t(m.samples) * bytes) return EC_IllegalParameter;
    // the values as stored pixels (two's complement when signed), components interleaved
    for (std::size_t i = 0; i < image.values.size(); ++i) {
      const std::int32_t v = image.values[i];
      switch (bytes) {
        case 1: static_cast<Uint8*>(buffer)[i] = Uint8(v); break;
        case 2: static_cast<Uint16*>(buffer)[i] = Uint16(v); break;
        default: static_cast<Uint32*>(buffer)[i] = Uint32(v); break;
      }
    }
    model = (m.photometric == "YBR_RCT" || m.photometric == "YBR_ICT") ? "RGB" : m.photometric.c_str();
    return EC_Normal;
  }

  OFCondition encode(const Uint16* pixels, const Uint32 length, const DcmRepresentationParameter* to,
                     DcmPixelSequence*& seq, const DcmCodecParameter*, DcmStack& stack,
                     OFBool& remove_old) const override {
    DcmItem* ds = dataset_of(stack);
    PixelModule m;
    if (OFCondition c = pixel_module(ds, m); c.bad()) return c;
    if (m.samples != 1 || m.bits_allocated > 16) return EC_CannotChangeRepresentation;
    const auto* param = dynamic_cast<const J2kParameter*>(to);
    const bool lossless = xfer_ == EXS_JPEG2000LosslessOnly || !param || param->lossless();
    const std::size_t n = std::size_t(m.rows) * std::size_t(m.cols);
    const std::size_t frame_bytes = n * std::size_t(m.bits_allocated / 8);
    if (std::size_t(length) < frame_bytes * std::size_t(m.frames)) return EC_CorruptedData;
    auto sequence = std::make_unique<DcmPixelSequence>(DcmTag(DCM_PixelData, EVR_OB));
    auto* offsets = new DcmPixelItem(DcmTag(DCM_Item, EVR_OB));
    sequence->insert(offsets);
    DcmOffsetList list;
    std::vector<std::int32_t> values(n);
    const auto* bytes = reinterpret_cast<const Uint8*>(pixels);
    for (long f = 0; f < m.frames; ++f) {
      for (std::size_t p = 0; p < n; ++p) {
        std::int64_t v = m.bits_allocated == 8 ? bytes[std::size_t(f) * frame_bytes + p]
                                               : pixels[std::size_t(f) * n + p];
        v &= (std::int64_t(1) << m.bits_stored) - 1;
        if (m.pixel_rep == 1 && (v >> (m.bits_stored - 1)) & 1) v -= std::int64_t(1) << m.bits_stored;
        values[p] = std::int32_t(v);
      }
      std::vector<std::uint8_t> code;
      try {
        code = encode_jpeg2000(values.data(), int(m.cols), int(m.rows), int(m.bits_stored), m.pixel_rep == 1, lossless,
                               param ? param->ratio() : 8.0);
      } catch (const Error&) {
        return EC_CannotChangeRepresentation;
      }
      if (sequence->storeCompressedFrame(list, code.data(), Uint32(code.size()), 0).bad()) return EC_MemoryExhausted;
    }
    if (offsets->createOffsetTable(list).bad()) return EC_MemoryExhausted;
    if (!lossless) {
      ds->putAndInsertString(DCM_LossyImageCompression, "01");
      ds->putAndInsertString(DCM_LossyImageCompressionMethod, "ISO_15444_1");
    }
    seq = sequence.release();
    remove_old = OFFalse;
    return EC_Normal;
  }

  OFCondition encode(const E_TransferSyntax, const DcmRepresentationParameter*, DcmPixelSequence*,
                     const DcmRepresentationParameter*, DcmPixelSequence*&, const DcmCodecParameter*, DcmStack&,
                     OFBool&) const override {
    return EC_IllegalCall;  // compressed to compressed: decode first
  }

  OFBool canChangeCoding(const E_TransferSyntax from, const E_TransferSyntax to) const override {
    const bool from_plain = !DcmXfer(from).isEncapsulated() && from != EXS_Unknown;
    const bool to_plain = !DcmXfer(to).isEncapsulated() && to != EXS_Unknown;
    return (from == xfer_ && to_plain) || (from_plain && to == xfer_);
  }

  OFCondition determineDecompressedColorModel(const DcmRepresentationParameter*, DcmPixelSequence*,
                                              const DcmCodecParameter*, DcmItem* ds, OFString& model) const override {
    PixelModule m;
    if (OFCondition c = pixel_module(ds, m); c.bad()) return c;
    model = (m.photometric == "YBR_RCT" || m.photometric == "YBR_ICT") ? "RGB" : m.photometric.c_str();
    return EC_Normal;
  }

 private:
  E_TransferSyntax xfer_;
};

}  // namespace

std::unique_ptr<DcmRepresentationParameter> jpeg2000_parameter(bool lossless, double compression_ratio) {
  return std::make_unique<J2kParameter>(lossless, compression_ratio);
}

void register_jpeg2000_codecs() {
  static std::once_flag once;
  std::call_once(once, [] {
    // kept for the life of the program, as DCMTK's own codecs are
    static const J2kCodecParameter codec_parameter;
    static const J2kParameter lossless(true), lossy(false);
    static const J2kCodec lossless_only(EXS_JPEG2000LosslessOnly), any(EXS_JPEG2000);
    DcmCodecList::registerCodec(&lossless_only, &lossless, &codec_parameter);
    DcmCodecList::registerCodec(&any, &lossy, &codec_parameter);
  });
}

}  // namespace vx::dicom
