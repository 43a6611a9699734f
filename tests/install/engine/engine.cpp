// A tiny engine in C++ (11 and 17), built against an installed hairfilter
// alone through hairfilter.hpp. engine URL VARIANT prints the same line as
// engine.c (for a variant that reads no estimate).
#include <cinttypes>
#include <cstdio>
#include <cstring>
#include <vector>

#include <hairfilter/hairfilter.hpp>

#include "engine_frame.h"

int main(int argc, char **argv) {
  if (argc != 3) return 2;
  if (hairfilter::version() != HAIRFILTER_VERSION_STRING) return 1;
  std::vector<float> features(ENGINE_W * ENGINE_H * ENGINE_SPP * 6);
  std::vector<float> filtered(ENGINE_W * ENGINE_H * 3);
  engine_features(features.data());
  try {
    hairfilter::Options opt;
    opt.client_name = "engine-cpp";
    hairfilter::Client hf(argv[1], opt);
    bool known = false, reads_estimate = false;
    for (const hfc_variant &v : hf.variants()) {
      known = known || v.spp == ENGINE_SPP;
      if (!std::strcmp(v.name, argv[2])) reads_estimate = v.estimate != 0;
    }
    if (!known) return 1;
    hairfilter::Request r;
    r.variant = argv[2];
    r.width = ENGINE_W;
    r.height = ENGINE_H;
    r.spp = ENGINE_SPP;
    r.set_features(features.data(), features.size() * sizeof(float));
    // A variant that reads the alpha-corrected estimate gets one from a
    // buffer of its own (here the samples' mean colour, highlight, alpha);
    // nullptr sends none.
    std::vector<float> estimate(ENGINE_W * ENGINE_H * 3);
    for (std::size_t p = 0; p < estimate.size(); p++)
      for (int k = 0; k < ENGINE_SPP; k++)
        estimate[p] += features[(p / 3 * ENGINE_SPP + k) * 6 + p % 3] / ENGINE_SPP;
    r.set_estimate(estimate.data(), estimate.size() * sizeof(float));
    if (!reads_estimate) r.set_estimate(nullptr, 0);
    r.set_result(filtered.data(), filtered.size() * sizeof(float));
    hairfilter::Status s = hf.filter(r);
    if (!s) {
      std::fprintf(stderr, "engine: %s\n", s.what().c_str());
      return 1;
    }
    std::printf("library %s server %s result %016" PRIx64 "\n", hairfilter::version().c_str(),
                hf.info().software_version,
                engine_hash(filtered.data(), filtered.size() * sizeof(float)));
  } catch (const hairfilter::Error &e) {
    std::fprintf(stderr, "engine: %s\n", e.what());
    return 1;
  }
  return 0;
}
