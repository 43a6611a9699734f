// filter_exr.cpp: a feature EXR filtered through hairfilterd, in C++ with
// OpenEXR's own API and hairfilter.hpp: the reading an engine or a tool needs
// for the files of protocol/FEATURES.md ("In EXR files"), from a dump of its
// own frames or from `hairfilter render frame`.
//
//   filter_exr URL FEATURES.exr RESULT.exr [VARIANT]
//
// VARIANT defaults to KernelMix (the bundled default; KernelAC on a server
// without it) for a file with the alpha-corrected estimate (acst4.*), else
// to Kernel. The samples are read by channel name (OpenEXR
// keeps channels sorted by name, so never by position): S{k}.color ...
// S{k}.tangent.y for the variant's spp, into [height][width][spp * 6]
// floats over the file's data window, HALF channels widened by OpenEXR. A
// variant that reads the estimate gets acst4.color, acst4.highlight and
// acst4.alpha from a buffer of their own. The result (color, highlight,
// alpha) is written with the input's data and display windows. Scanline or
// tiled files; of a multi-part file, the first part (`hairfilter filter
// --part` picks another). Exit status 0; 1 with the reason on stderr; 2
// for a wrong command line.
//
// Built in the source tree as build/client/lib/examples/filter_exr. From an
// installed hairfilter (its pkg-config file in PREFIX/lib/<arch>/pkgconfig,
// which PKG_CONFIG_PATH names unless PREFIX is /usr; the rpath finds
// libhairfilter.so where the loader does not look):
//   c++ -std=c++11 filter_exr.cpp $(pkg-config --cflags --libs hairfilter OpenEXR) -Wl,-rpath,$(pkg-config --variable=libdir hairfilter)
#include <cstdio>
#include <cstring>
#include <stdexcept>
#include <string>
#include <vector>

#include <strings.h>

#include <ImfChannelList.h>
#include <ImfFrameBuffer.h>
#include <ImfHeader.h>
#include <ImfInputFile.h>
#include <ImfOutputFile.h>

#include <hairfilter/hairfilter.hpp>

namespace {

// protocol/FEATURES.md's order of a sample's features.
const char *const kFeatures[6] = {"color", "highlight", "alpha", "depth", "tangent.x", "tangent.y"};
const char *const kEstimate[3] = {"acst4.color", "acst4.highlight", "acst4.alpha"};
const char *const kResult[3] = {"color", "highlight", "alpha"};

// Adds the channels `names` to fb as FLOAT slices of out, resized to
// [height][width][names.size()] over the data window dw. A missing channel
// is an error (OpenEXR would fill it with 0 without a word).
void add_slices(const Imf::Header &h, const std::vector<std::string> &names,
                const Imath::Box2i &dw, std::vector<float> &out, Imf::FrameBuffer &fb) {
  const std::size_t w = dw.max.x - dw.min.x + 1, rows = dw.max.y - dw.min.y + 1;
  const std::size_t n = names.size(), xs = n * sizeof(float);
  out.assign(w * rows * n, 0.0f);
  for (std::size_t c = 0; c < n; c++) {
    if (!h.channels().findChannel(names[c]))
      throw std::runtime_error("the file has no channel " + names[c]);
    // Make places pixel (dw.min.x, dw.min.y) at the buffer's start.
    fb.insert(names[c], Imf::Slice::Make(Imf::FLOAT, out.data() + c, dw, xs, xs * w));
  }
}

std::vector<std::string> sample_channels(int spp) {
  std::vector<std::string> names;
  for (int k = 0; k < spp; k++)
    for (const char *f : kFeatures) names.push_back("S" + std::to_string(k) + "." + f);
  return names;
}

}  // namespace

int main(int argc, char **argv) {
  if (argc < 4 || argc > 5) {
    std::fprintf(stderr, "usage: filter_exr URL FEATURES.exr RESULT.exr [VARIANT]\n");
    return 2;
  }
  try {
    Imf::InputFile in(argv[2]);
    const Imf::Header &head = in.header();
    const Imath::Box2i dw = head.dataWindow();
    const int width = dw.max.x - dw.min.x + 1, height = dw.max.y - dw.min.y + 1;
    const bool has_estimate = head.channels().findChannel(kEstimate[0]) != nullptr;
    hairfilter::Options opt;
    opt.client_name = "filter_exr";
    hairfilter::Client hf(argv[1], opt);
    std::vector<hfc_variant> variants = hf.variants();
    auto find = [&](const char *want) -> const hfc_variant * {
      for (const hfc_variant &x : variants)
        if (!strcasecmp(x.name, want)) return &x;  // as the server matches names
      return nullptr;
    };
    // The bundled default, KernelMix, where the file has the estimate and
    // the server has it; else KernelAC; else Kernel.
    std::string name = argc == 5       ? argv[4]
                       : !has_estimate ? "Kernel"
                       : find("KernelMix") ? "KernelMix"
                                           : "KernelAC";
    const hfc_variant *v = find(name.c_str());
    std::string listed;
    for (const hfc_variant &x : variants) listed += std::string(listed.empty() ? "" : ", ") + x.name;
    if (!v) throw std::runtime_error("the server has no variant " + name + "; it has " + listed);

    // One read of the rows for the samples and the estimate together.
    std::vector<float> features, estimate;
    Imf::FrameBuffer fb;
    add_slices(head, sample_channels(v->spp), dw, features, fb);
    if (v->estimate)
      add_slices(head, std::vector<std::string>(kEstimate, kEstimate + 3), dw, estimate, fb);
    in.setFrameBuffer(fb);
    in.readPixels(dw.min.y, dw.max.y);

    std::vector<float> result(static_cast<std::size_t>(width) * height * 3);
    hairfilter::Request r;
    r.variant = v->name;
    r.width = width;
    r.height = height;
    r.spp = v->spp;
    r.set_features(features.data(), features.size() * sizeof(float));
    if (v->estimate) r.set_estimate(estimate.data(), estimate.size() * sizeof(float));
    r.set_result(result.data(), result.size() * sizeof(float));
    hfc_timing t;
    hairfilter::Status s = hf.filter(r, &t);
    if (!s) throw std::runtime_error(v->name + std::string(": ") + s.what());
    if (t.out_of_range)
      std::fprintf(stderr, "filter_exr: %s is outside the range %s was trained on\n", argv[2],
                   v->name);
    if (t.input_sanitised)
      std::fprintf(stderr, "filter_exr: %s has NaN, infinite or out-of-range values, which the "
                   "server sanitised (protocol/FEATURES.md, \"Out-of-contract values\")\n",
                   argv[2]);

    Imf::Header out_head(head.displayWindow(), dw);
    out_head.compression() = Imf::ZIP_COMPRESSION;
    Imf::FrameBuffer ofb;
    for (int c = 0; c < 3; c++) {
      out_head.channels().insert(kResult[c], Imf::Channel(Imf::FLOAT));
      ofb.insert(kResult[c], Imf::Slice::Make(Imf::FLOAT, result.data() + c, dw,
                                              3 * sizeof(float), 3 * sizeof(float) * width));
    }
    Imf::OutputFile out(argv[3], out_head);
    out.setFrameBuffer(ofb);
    out.writePixels(height);
    std::printf("%s: %dx%d filtered by %s in %.0f us\n", argv[3], width, height, v->name,
                t.total_us);
  } catch (const std::exception &e) {
    // OpenEXR's Iex exceptions and hairfilter::Error are std::exceptions.
    std::fprintf(stderr, "filter_exr: %s\n", e.what());
    return 1;
  }
  return 0;
}
