/* filter_raw: one frame through libhairfilter, from and to raw files, so
 * that another client (test_python_client.py) can compare its results with
 * the C library's byte for byte.
 *
 *   filter_raw URL VARIANT WIDTH HEIGHT SPP f32|f16 IN OUT [shm] [rgba RGBA] [ca CA.pem]
 *              [estimate]
 *
 * IN holds the features [HEIGHT][WIDTH][SPP*6] in the dtype given (with
 * estimate, followed by the alpha-corrected estimate [HEIGHT][WIDTH][3],
 * sent with hfc_request.estimate); OUT gets
 * the result [HEIGHT][WIDTH][3] in the same dtype, RGBA the composite
 * (hair 0.45,0.25,0.12, light 1,1,1, background 0.18,0.2,0.24). With shm the
 * frame goes through a shared segment (and must: exit 3 otherwise). */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <hairfilter/hairfilter.h>

static void *slurp(const char *path, size_t want) {
  FILE *f = fopen(path, "rb");
  if (!f) return NULL;
  void *b = malloc(want ? want : 1);
  size_t got = b ? fread(b, 1, want, f) : 0;
  int extra = fgetc(f) != EOF;
  fclose(f);
  if (got != want || extra) {
    fprintf(stderr, "filter_raw: %s is not %zu bytes\n", path, want);
    free(b);
    return NULL;
  }
  return b;
}

static int spill(const char *path, const void *b, size_t n) {
  FILE *f = fopen(path, "wb");
  if (!f) return -1;
  size_t put = fwrite(b, 1, n, f);
  return fclose(f) == 0 && put == n ? 0 : -1;
}

int main(int argc, char **argv) {
  if (argc < 9) {
    fprintf(stderr, "usage: filter_raw URL VARIANT W H SPP f32|f16 IN OUT [shm] [rgba RGBA]\n");
    return 2;
  }
  int w = atoi(argv[3]), h = atoi(argv[4]), spp = atoi(argv[5]);
  hfc_dtype dt = strcmp(argv[6], "f16") ? HFC_F32 : HFC_F16;
  int shm = 0, estimate = 0;
  const char *rgba_path = NULL;
  hfc_options o;
  hfc_options_init(&o);
  for (int i = 9; i < argc; i++) {
    if (!strcmp(argv[i], "shm")) shm = 1;
    if (!strcmp(argv[i], "estimate")) estimate = 1;
    if (!strcmp(argv[i], "rgba") && i + 1 < argc) rgba_path = argv[++i];
    if (!strcmp(argv[i], "ca") && i + 1 < argc) o.tls_ca_file = argv[++i];
  }
  size_t in_b = hfc_features_bytes(w, h, spp, dt) + (estimate ? hfc_estimate_bytes(w, h, dt) : 0);
  size_t out_b = hfc_output_bytes(w, h, 3, dt);
  size_t rgba_b = rgba_path ? hfc_output_bytes(w, h, 4, dt) : 0;
  void *in = slurp(argv[7], in_b);
  if (!in) return 1;
  hfc_client *c;
  int rc = hfc_connect(argv[1], &o, &c);
  if (rc) {
    fprintf(stderr, "filter_raw: %s: %s\n", hfc_strerror(rc), hfc_last_message(NULL));
    return 1;
  }
  uint8_t *mem = NULL, *out;
  if (shm) {
    if ((rc = hfc_shm_alloc(c, in_b + out_b + rgba_b, (void **)&mem))) {
      fprintf(stderr, "filter_raw: shm: %s\n", hfc_last_message(c));
      return 1;
    }
    memcpy(mem, in, in_b);
    out = mem + in_b;
  } else {
    out = malloc(out_b + rgba_b);
  }
  hfc_request r;
  hfc_request_init(&r);
  r.variant = argv[2];
  r.width = w;
  r.height = h;
  r.spp = spp;
  r.in_dtype = r.out_dtype = dt;
  r.features = shm ? mem : in;
  r.features_bytes = in_b;
  r.estimate = estimate;
  r.result = out;
  r.result_bytes = out_b;
  if (rgba_path) {
    r.rgba = out + out_b;
    r.rgba_bytes = rgba_b;
    const float hair[3] = {0.45f, 0.25f, 0.12f}, light[3] = {1, 1, 1}, bg[3] = {0.18f, 0.2f, 0.24f};
    memcpy(r.hair, hair, sizeof hair);
    memcpy(r.light, light, sizeof light);
    memcpy(r.background, bg, sizeof bg);
  }
  hfc_timing t;
  if ((rc = hfc_filter(c, &r, &t))) {
    fprintf(stderr, "filter_raw: %s: %s\n", hfc_strerror(rc), hfc_last_message(c));
    return 1;
  }
  if (shm && !t.via_shm) return 3;
  if (spill(argv[8], out, out_b) || (rgba_path && spill(rgba_path, out + out_b, rgba_b))) {
    fprintf(stderr, "filter_raw: cannot write the result\n");
    return 1;
  }
  hfc_close(c);
  free(in);
  if (!shm) free(out);
  return 0;
}
