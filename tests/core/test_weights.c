/* The safetensors loader against valid, corrupt and hostile files. Each
 * corrupt file must give a clean error (never a crash, never weights). */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>
#include <cmocka.h>

#include "hfcore.h"

typedef struct blob {
  unsigned char *data;
  size_t len;
} blob;

static char tmpdir[] = "/tmp/hf_test_weights_XXXXXX";

static blob read_all(const char *path) {
  blob b = {0};
  FILE *f = fopen(path, "rb");
  assert_non_null(f);
  fseek(f, 0, SEEK_END);
  b.len = (size_t)ftell(f);
  rewind(f);
  b.data = malloc(b.len);
  assert_int_equal(fread(b.data, 1, b.len, f), b.len);
  fclose(f);
  return b;
}

/* A valid Small model's file. */
static blob valid_file(hf_weights **w_out) {
  hf_net_config c;
  hf_variant_preset("Small", &c);
  hf_weights *w;
  assert_int_equal(hf_weights_init_random(&c, 42, &w), HF_OK);
  char path[256];
  snprintf(path, sizeof path, "%s/small.safetensors", tmpdir);
  assert_int_equal(hf_weights_save(path, w), HF_OK);
  if (w_out) *w_out = w;
  else hf_weights_free(w);
  return read_all(path);
}

static uint64_t hlen_of(const blob *b) {
  uint64_t v = 0;
  for (int i = 7; i >= 0; i--) v = (v << 8) | b->data[i];
  return v;
}

/* Rebuilds the file with the header's first `from` replaced by `to`. */
static blob with_header_edit(const blob *b, const char *from, const char *to) {
  uint64_t hl = hlen_of(b);
  char *h = malloc(hl + 1);
  memcpy(h, b->data + 8, hl);
  h[hl] = 0;
  char *at = strstr(h, from);
  assert_non_null(at);
  size_t nh = hl - strlen(from) + strlen(to);
  blob o = {malloc(8 + nh + (b->len - 8 - hl)), 8 + nh + (b->len - 8 - hl)};
  for (int i = 0; i < 8; i++) o.data[i] = (unsigned char)((uint64_t)nh >> (8 * i));
  size_t pre = (size_t)(at - h);
  memcpy(o.data + 8, h, pre);
  memcpy(o.data + 8 + pre, to, strlen(to));
  memcpy(o.data + 8 + pre + strlen(to), at + strlen(from), hl - pre - strlen(from));
  memcpy(o.data + 8 + nh, b->data + 8 + hl, b->len - 8 - hl);
  free(h);
  return o;
}

/* Rebuilds the file with suffix after the header's JSON (inside the
 * header's declared length). */
static blob with_header_suffix(const blob *b, const char *suffix, size_t k) {
  uint64_t hl = hlen_of(b);
  blob o = {malloc(b->len + k), b->len + k};
  assert_non_null(o.data);
  for (int i = 0; i < 8; i++) o.data[i] = (unsigned char)((hl + k) >> (8 * i));
  memcpy(o.data + 8, b->data + 8, hl);
  memcpy(o.data + 8 + hl, suffix, k);
  memcpy(o.data + 8 + hl + k, b->data + 8 + hl, b->len - 8 - hl);
  return o;
}

static void expect_reject(const blob *b, int want_rc, const char *want_in_msg) {
  hf_weights *w = (hf_weights *)0x1;
  char err[512] = "";
  int rc = hf_weights_load_mem(b->data, b->len, &w, err, sizeof err);
  if (want_rc) assert_int_equal(rc, want_rc);
  else assert_true(rc < 0);
  assert_null(w);
  assert_true(strlen(err) > 0);
  if (want_in_msg && !strstr(err, want_in_msg)) fail_msg("error '%s' lacks '%s'", err, want_in_msg);
}

static void test_roundtrip_bit_exact(void **state) {
  hf_weights *w;
  blob b = valid_file(&w);
  hf_weights *r;
  char err[256];
  assert_int_equal(hf_weights_load_mem(b.data, b.len, &r, err, sizeof err), HF_OK);
  assert_int_equal(r->num_params, w->num_params);
  assert_memory_equal(r->storage, w->storage, w->num_params * sizeof(float));
  assert_string_equal(r->cfg.name, "Small");
  assert_int_equal(r->cfg.num_levels, 3);
  assert_int_equal(r->cfg.levels[2], 64);
  assert_string_equal(r->features[4], "tangent.x");
  /* and through the path-based loader */
  char path[256];
  snprintf(path, sizeof path, "%s/small.safetensors", tmpdir);
  hf_weights *r2;
  assert_int_equal(hf_weights_load(path, &r2, err, sizeof err), HF_OK);
  assert_memory_equal(r2->storage, w->storage, w->num_params * sizeof(float));
  hf_weights_free(r2);
  hf_weights_free(r);
  hf_weights_free(w);
  free(b.data);
}

/* KernelMix's kernel_mix survives a save and a load; a file that says
 * kernel_mix without the estimate, or another value than 0 or 1, or
 * out_channels without the mixing channel, is refused by name. */
static void test_kernel_mix_metadata(void **state) {
  (void)state;
  hf_net_config c;
  assert_int_equal(hf_variant_preset("KernelMix", &c), HF_OK);
  hf_weights *w, *r;
  assert_int_equal(hf_weights_init_random(&c, 5, &w), HF_OK);
  char path[256], err[512];
  snprintf(path, sizeof path, "%s/mix.safetensors", tmpdir);
  assert_int_equal(hf_weights_save(path, w), HF_OK);
  assert_int_equal(hf_weights_load(path, &r, err, sizeof err), HF_OK);
  assert_int_equal(r->cfg.kernel_mix, 1);
  assert_int_equal(r->cfg.out_channels, 49 + 3 + 1);
  assert_memory_equal(r->storage, w->storage, w->num_params * sizeof(float));
  hf_weights_free(r);
  hf_weights_free(w);
  blob b = read_all(path);
  blob two = with_header_edit(&b, "\\\"kernel_mix\\\":1", "\\\"kernel_mix\\\":2");
  expect_reject(&two, HF_EFORMAT, "'kernel_mix' is not 0 or 1");
  blob none = with_header_edit(&b, "\\\"estimate\\\":\\\"alpha_corrected\\\"",
                               "\\\"estimate\\\":\\\"none\\\"");
  expect_reject(&none, HF_EFORMAT, "in_channels");
  blob none24 = with_header_edit(&none, "\\\"in_channels\\\":27", "\\\"in_channels\\\":24");
  expect_reject(&none24, HF_EFORMAT, "it needs 'estimate' \"alpha_corrected\"");
  blob out = with_header_edit(&b, "\\\"out_channels\\\":53", "\\\"out_channels\\\":52");
  expect_reject(&out, HF_EFORMAT, "+ 1 for kernel_mix");
  free(two.data), free(none.data), free(none24.data), free(out.data), free(b.data);
}

/* hf_weights_save writes beside the file and renames: a reader that has
 * the old file open reads it whole (written in place, it read the new
 * file's bytes after its first 100), and a failed save leaves the old file
 * as it was, with no temporary behind. */
static void test_save_replaces_whole(void **state) {
  (void)state;
  char path[256], tmp[300];
  snprintf(path, sizeof path, "%s/replaced.safetensors", tmpdir);
  snprintf(tmp, sizeof tmp, "%s.tmp", path);
  hf_net_config c;
  hf_weights *a, *b;
  hf_variant_preset("Small", &c);
  assert_int_equal(hf_weights_init_random(&c, 1, &a), HF_OK);
  hf_variant_preset("Shallow", &c);
  assert_int_equal(hf_weights_init_random(&c, 2, &b), HF_OK);
  assert_int_equal(hf_weights_save(path, a), HF_OK);
  blob old = read_all(path);
  FILE *f = fopen(path, "rb");
  assert_non_null(f);
  unsigned char *seen = malloc(old.len + 1);
  assert_non_null(seen);
  assert_int_equal(fread(seen, 1, 100, f), 100);
  assert_int_equal(hf_weights_save(path, b), HF_OK);
  assert_int_equal(fread(seen + 100, 1, old.len + 1 - 100, f), old.len - 100);
  fclose(f);
  assert_memory_equal(seen, old.data, old.len);
  struct stat st;
  assert_int_not_equal(stat(tmp, &st), 0);
  /* A save that cannot complete (its temporary's name taken by a
   * directory): the file there is the one before. */
  blob now = read_all(path);
  assert_int_equal(mkdir(tmp, 0755), 0);
  assert_int_equal(hf_weights_save(path, a), HF_EIO);
  assert_int_equal(rmdir(tmp), 0);
  blob after = read_all(path);
  assert_int_equal(after.len, now.len);
  assert_memory_equal(after.data, now.data, now.len);
  free(seen);
  free(old.data);
  free(now.data);
  free(after.data);
  hf_weights_free(a);
  hf_weights_free(b);
}

static void test_truncated(void **state) {
  blob b = valid_file(NULL);
  size_t cuts[] = {0, 4, 8, 20, (size_t)hlen_of(&b) + 8, b.len - 1};
  for (size_t k = 0; k < sizeof cuts / sizeof cuts[0]; k++) {
    blob t = {b.data, cuts[k]};
    expect_reject(&t, 0, NULL);
  }
  free(b.data);
}

static void test_huge_header_length(void **state) {
  blob b = valid_file(NULL);
  uint64_t lens[] = {UINT64_MAX, (uint64_t)1 << 40, b.len, b.len - 7, 1};
  for (size_t k = 0; k < sizeof lens / sizeof lens[0]; k++) {
    for (int i = 0; i < 8; i++) b.data[i] = (unsigned char)(lens[k] >> (8 * i));
    expect_reject(&b, HF_EFORMAT, NULL);
  }
  free(b.data);
}

static void test_offsets_past_end(void **state) {
  blob b = valid_file(NULL);
  /* enc0.weight starts at 0: push its end far beyond the data */
  blob o = with_header_edit(&b, "\"data_offsets\":[0,", "\"data_offsets\":[99999999,");
  expect_reject(&o, HF_EFORMAT, "data_offsets [99999999, 13824] end before they begin");
  free(o.data);
  blob n = with_header_edit(&b, "\"data_offsets\":[0,", "\"data_offsets\":[-8,");
  expect_reject(&n, HF_EFORMAT, "are not two byte offsets");
  free(n.data);
  blob f = with_header_edit(&b, "\"data_offsets\":[0,", "\"data_offsets\":[1e300,");
  expect_reject(&f, HF_EFORMAT, NULL);
  free(f.data);
  blob s = with_header_edit(&b, "\"data_offsets\":[0,", "\"data_offsets\":[\"0\",");
  expect_reject(&s, HF_EFORMAT, "data_offsets holds a string, not two integers");
  free(s.data);
  free(b.data);
}

static void test_wrong_shapes(void **state) {
  blob b = valid_file(NULL);
  blob o = with_header_edit(&b, "\"shape\":[16,24,3,3]", "\"shape\":[16,24,3,4]");
  expect_reject(&o, HF_EFORMAT, "enc0.weight");
  free(o.data);
  blob d = with_header_edit(&b, "\"shape\":[16,24,3,3]", "\"shape\":[16,24,9]");
  expect_reject(&d, HF_EFORMAT, "dimensions");
  free(d.data);
  /* metadata says other channel counts than the tensors have */
  blob m = with_header_edit(&b, "[16,32,64]", "[16,32,65]");
  expect_reject(&m, HF_EFORMAT, NULL);
  free(m.data);
  free(b.data);
}

static void test_bad_json(void **state) {
  blob b = valid_file(NULL);
  blob o = with_header_edit(&b, "{\"__metadata__\"", "[\"__metadata__\"");
  expect_reject(&o, HF_EFORMAT, "JSON");
  free(o.data);
  blob m = with_header_edit(&b, "\"__metadata__\"", "\"__metadatum__\"");
  expect_reject(&m, HF_EFORMAT, "hairfilter");
  free(m.data);
  blob n = with_header_edit(&b, "{\\\"name\\\"", "{{\\\"name\\\"");
  expect_reject(&n, HF_EFORMAT, "metadata");
  free(n.data);
  blob f = with_header_edit(&b, "\\\"tangent.x\\\"", "\\\"tangent.z\\\"");
  expect_reject(&f, HF_EFORMAT, "features");
  free(f.data);
  blob s = with_header_edit(&b, "\\\"spp\\\":4", "\\\"spp\\\":3");
  expect_reject(&s, HF_EFORMAT, "in_channels");
  free(s.data);
  /* Counts far outside int (fuzz regression tests/fuzz/regressions/weights):
   * refused, never converted (that was undefined behaviour); those with a
   * fraction or an exponent are refused as no integer before their range. */
  static const char *const huge[] = {"1e100", "-1e100", "4294967297", "2.5"};
  for (int i = 0; i < 4; i++) {
    char to[64];
    snprintf(to, sizeof to, "\\\"spp\\\":%s", huge[i]);
    blob h = with_header_edit(&b, "\\\"spp\\\":4", to);
    expect_reject(&h, HF_EFORMAT, strchr(huge[i], 'e') || strchr(huge[i], '.')
                                      ? "'spp' holds"
                                      : "'spp' missing or not an integer in 1..16");
    free(h.data);
  }
  blob a = with_header_edit(&b, "\\\"arch\\\":\\\"unet\\\"", "\\\"arch\\\":\\\"gan\\\"");
  expect_reject(&a, HF_EUNSUPPORTED, "arch");
  free(a.data);
  free(b.data);
}

/* One JSON value and nothing after it, in the header and in the metadata
 * strings: bytes after the closing brace were ignored (cJSON_Parse stops
 * there), while safetensors' own reader refuses them. */
static void test_trailing_json(void **state) {
  blob b = valid_file(NULL);
  /* Bytes JSON does not call whitespace, a control byte and a NUL with
   * bytes after it included (cJSON's own end check passes both). */
  static const struct {
    const char *bytes;
    size_t len;
  } after[] = {{"xyz", 3}, {"\x01", 1}, {" \0junk", 6}};
  for (size_t i = 0; i < sizeof after / sizeof after[0]; i++) {
    blob o = with_header_suffix(&b, after[i].bytes, after[i].len);
    expect_reject(&o, HF_EFORMAT, "header is not valid JSON");
    free(o.data);
  }
  blob m = with_header_edit(&b, "\\\"tangent.y\\\"]}", "\\\"tangent.y\\\"]}garbage");
  expect_reject(&m, HF_EFORMAT, "metadata 'hairfilter' is not one JSON object");
  free(m.data);
  blob r = with_header_edit(&b, "\"__metadata__\":{",
                            "\"__metadata__\":{\"input_range\":\"{\\\"definition\\\":1,"
                            "\\\"spp\\\":4}{}\",");
  expect_reject(&r, HF_EFORMAT, "input_range is not a JSON object");
  free(r.data);
  /* safetensors pads its header with spaces, and JSON's whitespace is
   * allowed: still one value. */
  blob p = with_header_suffix(&b, "  \t\r\n  ", 7);
  hf_weights *w = NULL;
  char err[512] = "";
  assert_int_equal(hf_weights_load_mem(p.data, p.len, &w, err, sizeof err), HF_OK);
  hf_weights_free(w);
  free(p.data);
  free(b.data);
}

/* Metadata claiming a network far larger than the file (8 levels of 4096
 * channels: 4.5 billion parameters, 18 GB of float32, in a 300 KB file) is
 * refused by the tensor checks before the network is allocated: under a
 * 1 GB address space limit the refusal is the tensor count's, not an
 * allocation failure's. (Not under AddressSanitizer, which reserves far
 * more address space itself.) */
static void test_checked_before_allocation(void **state) {
  blob b = valid_file(NULL);
  blob h = with_header_edit(&b, "\\\"levels\\\":[16,32,64]",
                            "\\\"levels\\\":[4096,4096,4096,4096,4096,4096,4096,4096]");
  expect_reject(&h, HF_EFORMAT, "configuration needs");
#if defined(__SANITIZE_ADDRESS__)
  fprintf(stderr, "test_checked_before_allocation: the address space limit is skipped under "
                  "AddressSanitizer\n");
#else
  pid_t pid = fork();
  assert_true(pid >= 0);
  if (pid == 0) {
    struct rlimit lim = {(rlim_t)1 << 30, (rlim_t)1 << 30};
    if (setrlimit(RLIMIT_AS, &lim) != 0) _exit(3);
    hf_weights *w = NULL;
    char err[512] = "";
    int rc = hf_weights_load_mem(h.data, h.len, &w, err, sizeof err);
    if (rc == HF_EFORMAT && strstr(err, "configuration needs")) _exit(0);
    fprintf(stderr, "under 1 GB: %d %s\n", rc, err);
    _exit(1);
  }
  int status = 0;
  assert_int_equal(waitpid(pid, &status, 0), pid);
  assert_true(WIFEXITED(status));
  assert_int_equal(WEXITSTATUS(status), 0);
#endif
  free(h.data);
  free(b.data);
}

static void test_bad_dtype_and_tensor_set(void **state) {
  blob b = valid_file(NULL);
  blob d = with_header_edit(&b, "\"dtype\":\"F32\"", "\"dtype\":\"I64\"");
  expect_reject(&d, HF_EUNSUPPORTED, "dtype");
  free(d.data);
  /* F16 with F32-sized data: byte count mismatch */
  blob h = with_header_edit(&b, "\"dtype\":\"F32\"", "\"dtype\":\"F16\"");
  expect_reject(&h, HF_EFORMAT, "bytes");
  free(h.data);
  blob r = with_header_edit(&b, "\"enc0.bias\"", "\"enc9.bias\"");
  expect_reject(&r, HF_EFORMAT, "enc0.bias");
  free(r.data);
  free(b.data);
}

/* The tensors' byte ranges tile the data (the safetensors reference
 * reader's rule), and the header starts with '{'. Small's enc0.weight is
 * [0, 13824), enc0.bias [13824, 13888). */
static void test_tiling_and_header_start(void **state) {
  blob b = valid_file(NULL);
  blob o = with_header_edit(&b, "[13824,13888]", "[13760,13824]");
  expect_reject(&o, HF_EFORMAT, "data_offsets [13760, 13824) overlap tensor 'enc0.weight' [0, 13824)");
  free(o.data);
  blob t = {malloc(b.len + 16), b.len + 16};
  memcpy(t.data, b.data, b.len);
  memset(t.data + b.len, 0, 16);
  expect_reject(&t, HF_EFORMAT, "16 bytes after the last tensor");
  free(t.data);
  blob m = with_header_edit(&b, "{\"__metadata__\"", "\xef\xbb\xbf{\"__metadata__\"");
  expect_reject(&m, HF_EFORMAT, "does not start with '{'");
  free(m.data);
  free(b.data);
}

/* A NaN or infinite weight is refused, naming the tensor and the value:
 * loaded, it made every pixel it reached NaN, which the output guard
 * turned into neutral values blamed on the frames. */
static void test_nonfinite_values(void **state) {
  static const unsigned char nan_f32[4] = {0x00, 0x00, 0xc0, 0x7f}, inf_f32[4] = {0, 0, 0x80, 0x7f},
                             ninf_f32[4] = {0, 0, 0x80, 0xff};
  const unsigned char *vals[] = {nan_f32, inf_f32, ninf_f32};
  for (int v = 0; v < 3; v++)
    for (int last = 0; last < 2; last++) {
      blob b = valid_file(NULL);
      size_t at = last ? b.len - 4 : 8 + (size_t)hlen_of(&b);
      memcpy(b.data + at, vals[v], 4);
      expect_reject(&b, HF_EFORMAT, "is not finite (NaN or infinite)");
      free(b.data);
    }
  /* The largest finite float is a weight like any other. */
  blob b = valid_file(NULL);
  static const unsigned char max_f32[4] = {0xff, 0xff, 0x7f, 0x7f};
  memcpy(b.data + 8 + hlen_of(&b), max_f32, 4);
  hf_weights *w = NULL;
  char err[256];
  assert_int_equal(hf_weights_load_mem(b.data, b.len, &w, err, sizeof err), HF_OK);
  hf_weights_free(w);
  free(b.data);
}

/* A name twice in one JSON object, at any level, is refused: cJSON would
 * read the first and Python's json the last, two different networks. */
static void test_duplicate_keys(void **state) {
  blob b = valid_file(NULL);
  blob t = with_header_edit(&b, "\"enc0.bias\":", "\"enc0.bias\":{},\"enc0.bias\":");
  expect_reject(&t, HF_EFORMAT, "duplicate key 'enc0.bias'");
  free(t.data);
  blob d = with_header_edit(&b, "\"dtype\":\"F32\"", "\"dtype\":\"F32\",\"dtype\":\"F16\"");
  expect_reject(&d, HF_EFORMAT, "duplicate key 'dtype' in 'enc0.weight'");
  free(d.data);
  blob m = with_header_edit(&b, "{\"__metadata__\":",
                            "{\"__metadata__\":{\"hairfilter\":\"{}\"},\"__metadata__\":");
  expect_reject(&m, HF_EFORMAT, "duplicate key '__metadata__'");
  free(m.data);
  blob k = with_header_edit(&b, "\"__metadata__\":{", "\"__metadata__\":{\"x\":\"1\",\"x\":\"2\",");
  expect_reject(&k, HF_EFORMAT, "duplicate key 'x' in '__metadata__'");
  free(k.data);
  blob h = with_header_edit(&b, "\\\"spp\\\":4", "\\\"spp\\\":4,\\\"spp\\\":1");
  expect_reject(&h, HF_EFORMAT, "metadata 'hairfilter': duplicate key 'spp'");
  free(h.data);
  blob r = with_header_edit(&b, "\"__metadata__\":{",
                            "\"__metadata__\":{\"input_range\":\"{\\\"definition\\\":1,"
                            "\\\"definition\\\":2}\",");
  expect_reject(&r, HF_EFORMAT, "input_range: duplicate key 'definition'");
  free(r.data);
  /* Many names, the repeated one last: found, and quickly (sorted, not
   * pairwise). */
  size_t n = 200000, cap = n * 16 + 64, used = 0;
  char *many = malloc(cap);
  used += (size_t)snprintf(many, cap, "\"__metadata__\":{");
  for (size_t i = 0; i < n; i++) used += (size_t)snprintf(many + used, cap - used, "\"k%zu\":\"\",", i);
  snprintf(many + used, cap - used, "\"k7\":\"\",");
  blob g = with_header_edit(&b, "\"__metadata__\":{", many);
  expect_reject(&g, HF_EFORMAT, "duplicate key 'k7' in '__metadata__'");
  free(g.data);
  free(many);
  /* The field case: __metadata__ twice, first unet, then residual. */
  char path[512];
  snprintf(path, sizeof path, "%s/field/weights-duplicate-metadata.safetensors", HF_TEST_DATA);
  blob f = read_all(path);
  expect_reject(&f, HF_EFORMAT, "duplicate key '__metadata__'");
  hf_weights *w = (hf_weights *)0x1;
  char err[512];
  assert_int_equal(hf_weights_load(path, &w, err, sizeof err), HF_EFORMAT);
  assert_null(w);
  assert_non_null(strstr(err, "weights-duplicate-metadata.safetensors"));
  free(f.data);
  free(b.data);
}

/* A header is UTF-8 JSON (the safetensors format; its reference reader
 * refuses any other bytes), and a name or string with \u0000 cannot be
 * kept in C: "enc0.bias\u0000x" read as "enc0.bias" would load a tensor
 * that other readers call by another name. Both are refused, at every
 * level of JSON (the header, the 'hairfilter' and 'input_range' texts). */
static void test_header_text(void **state) {
  blob b = valid_file(NULL);
  static const struct {
    const char *from, *to, *want;
  } bad[] = {
    {"\"enc0.bias\":", "\"enc0.bias\\u0000x\":", "\\u0000"},
    {"\"enc0.bias\":", "\"enc0.bias\\u0000\":", "\\u0000"},
    {"\"__metadata__\":{", "\"__metadata__\":{\"note\":\"a\\u0000\",", "\\u0000"},
    {"\"__metadata__\":{", "\"__metadata__\":{\"note\":\"\xc3\x28\",", "UTF-8"},
    {"\"__metadata__\":{", "\"__metadata__\":{\"note\":\"\xed\xa0\x80\",", "UTF-8"},
    {"\"__metadata__\":{", "\"__metadata__\":{\"note\":\"\xc0\xaf\",", "UTF-8"},
    {"\"__metadata__\":{", "\"__metadata__\":{\"note\":\"\xf4\x90\x80\x80\",", "UTF-8"},
    {"\"__metadata__\":{", "\"__metadata__\":{\"note\":\"\xe2\x82\",", "UTF-8"},
    {"\"enc0.bias\":", "\"enc0.bias\xff\":", "UTF-8"},
    {"\\\"spp\\\":4", "\\\"spp\\\":4,\\\"x\\\\u0000\\\":1", "metadata 'hairfilter'"},
    /* Half of a UTF-16 surrogate pair, alone: no character (cJSON refuses
     * it, Python's json takes it), said as such, not "not valid JSON". */
    {"\"enc0.bias\":", "\"enc0.bias\\ud800\":", "half of a UTF-16 surrogate pair"},
    {"\"enc0.bias\":", "\"enc0.bias\\uDC00x\":", "half of a UTF-16 surrogate pair"},
    {"\"__metadata__\":{", "\"__metadata__\":{\"note\":\"\\udbff\\u0041\",",
     "half of a UTF-16 surrogate pair"},
    {"\\\"spp\\\":4", "\\\"spp\\\":4,\\\"x\\\\ud800\\\":1", "metadata 'hairfilter' holds a"},
    {"\"shape\":[16]", "\"shape\":[true]", "shape holds true, not an integer"},
    /* Numbers JSON's grammar does not allow, which cJSON reads with strtod
     * (016 as 16) and Python's json refuses: anywhere, at every level. */
    {"\"shape\":[16,24,3,3]", "\"shape\":[016,24,3,3]", "a number JSON does not allow"},
    {"\"shape\":[16,24,3,3]", "\"shape\":[16.,24,3,3]", "a number JSON does not allow"},
    {"\"data_offsets\":[0,", "\"data_offsets\":[00,", "a number JSON does not allow"},
    {"\\\"spp\\\":4", "\\\"spp\\\":04", "metadata 'hairfilter' holds a number JSON"},
    {"\\\"spp\\\":4", "\\\"spp\\\":4,\\\"x\\\":-.5", "metadata 'hairfilter' holds a number"},
  };
  for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++) {
    blob t = with_header_edit(&b, bad[i].from, bad[i].to);
    expect_reject(&t, HF_EFORMAT, bad[i].want);
    free(t.data);
  }
  /* Shapes and offsets written as fractions or exponents ("16.0", "1.6e1"):
   * integers to cJSON, not to safetensors' reference reader. Elsewhere
   * (a metadata string, a number in another place) such a number is no
   * concern of this check. */
  static const struct {
    const char *from, *to, *want;
  } nonint[] = {
    {"\"shape\":[16,24,3,3]", "\"shape\":[16.0,24,3,3]", "shape holds 16.0, not an integer"},
    {"\"shape\":[16,24,3,3]", "\"shape\":[1.6e1,24,3,3]", "shape holds 1.6e1"},
    {"\"shape\":[16,24,3,3]", "\"shape\":[16,24,3,3E0]", "shape holds 3E0"},
    {"\"data_offsets\":[0,", "\"data_offsets\":[0.0,", "'enc0.weight': data_offsets holds 0.0"},
  };
  for (size_t i = 0; i < sizeof nonint / sizeof nonint[0]; i++) {
    blob t = with_header_edit(&b, nonint[i].from, nonint[i].to);
    expect_reject(&t, HF_EFORMAT, nonint[i].want);
    free(t.data);
  }
  /* A key written with escapes is the key it decodes to, to cJSON and
   * Python's json alike: the check goes by the decoded name too. */
  static const struct {
    const char *from, *to, *want;
  } escaped[] = {
    {"\"shape\":[16,24,3,3]", "\"sh\\u0061pe\":[16.0,24,3,3]", "shape holds 16.0"},
    {"\"data_offsets\":[0,", "\"data\\u005foffsets\":[0.0,", "data_offsets holds 0.0"},
    {"\\\"spp\\\":4", "\\\"sp\\\\u0070\\\":4.0", "'spp' holds 4.0"},
    {"\\\"spp\\\":4", "\\\"\\\\u0073pp\\\":4E0", "'spp' holds 4E0"},
  };
  for (size_t i = 0; i < sizeof escaped / sizeof escaped[0]; i++) {
    blob t = with_header_edit(&b, escaped[i].from, escaped[i].to);
    expect_reject(&t, HF_EFORMAT, escaped[i].want);
    free(t.data);
  }
  blob fine = with_header_edit(&b, "\"__metadata__\":{", "\"__metadata__\":{\"shape\":\"[1.5]\",");
  hf_weights *fw = NULL;
  char ferr[512] = "";
  assert_int_equal(hf_weights_load_mem(fine.data, fine.len, &fw, ferr, sizeof ferr), HF_OK);
  hf_weights_free(fw);
  free(fine.data);
  /* The inner text's fault is named as such. */
  blob n = with_header_edit(&b, "\\\"spp\\\":4", "\\\"spp\\\":4,\\\"x\\\\u0000\\\":1");
  expect_reject(&n, HF_EFORMAT, "\\u0000");
  free(n.data);
  /* Escapes that are not \u0000, and UTF-8 of every length, load. */
  blob ok = with_header_edit(&b, "\"__metadata__\":{",
                             "\"__metadata__\":{\"note\":\"\\\\u0000 \\u0001 h\xc3\xa9 "
                             "\xe2\x82\xac \xf0\x9f\x98\x80 \xf4\x8f\xbf\xbf\",");
  hf_weights *w = NULL;
  char err[512] = "";
  assert_int_equal(hf_weights_load_mem(ok.data, ok.len, &w, err, sizeof err), HF_OK);
  hf_weights_free(w);
  free(ok.data);
  free(b.data);
}

/* safetensors: "__metadata__" is an object whose values are strings. */
static void test_metadata_types(void **state) {
  blob b = valid_file(NULL);
  blob n = with_header_edit(&b, "\"__metadata__\":{", "\"__metadata__\":{\"epoch\":3,");
  expect_reject(&n, HF_EFORMAT, "'__metadata__.epoch' is a number, but safetensors metadata "
                                "values are strings");
  free(n.data);
  blob o = with_header_edit(&b, "\"__metadata__\":{", "\"__metadata__\":{\"more\":{},");
  expect_reject(&o, HF_EFORMAT, "'__metadata__.more' is an object");
  free(o.data);
  blob a = with_header_edit(&b, "{\"__metadata__\":{", "{\"__metadata__\":[],\"x\":{");
  expect_reject(&a, HF_EFORMAT, "'__metadata__' is an array, but safetensors wants an object");
  free(a.data);
  free(b.data);
}

/* A Kernel file (the preset: radius 3, a 32-channel head) and one without
 * a head (radius 2) read back bit for bit; the kernel's metadata keys and
 * head tensors are checked like the rest. */
static void test_kernel_arch(void **state) {
  hf_net_config c;
  assert_int_equal(hf_variant_preset("Kernel", &c), HF_OK);
  hf_weights *w, *r;
  assert_int_equal(hf_weights_init_random(&c, 5, &w), HF_OK);
  assert_non_null(w->head_w);
  char path[256], err[256];
  snprintf(path, sizeof path, "%s/kernel.safetensors", tmpdir);
  assert_int_equal(hf_weights_save(path, w), HF_OK);
  assert_int_equal(hf_weights_load(path, &r, err, sizeof err), HF_OK);
  assert_int_equal(r->cfg.arch, HF_ARCH_KERNEL);
  assert_int_equal(r->cfg.kernel_radius, 3);
  assert_int_equal(r->cfg.kernel_hidden, 32);
  assert_int_equal(r->cfg.out_channels, 52);
  assert_int_equal(r->num_params, w->num_params);
  assert_memory_equal(r->storage, w->storage, w->num_params * sizeof(float));
  assert_memory_equal(r->head_w, w->head_w, 52 * 56 * sizeof(float));
  assert_memory_equal(r->head_b, w->head_b, 52 * sizeof(float));
  hf_weights_free(r);
  blob b = read_all(path);
  /* The head is optional in the metadata, not in the tensors: without
   * kernel_hidden the file's head tensors are extra. */
  blob h0 = with_header_edit(&b, ",\\\"kernel_hidden\\\":32", "");
  expect_reject(&h0, HF_EFORMAT, "tensors");
  free(h0.data);
  static const struct { const char *from, *to, *msg; } edits[] = {
    {"\\\"kernel_radius\\\":3", "\\\"kernel_radius\\\":5", "kernel_radius"},
    {"\\\"kernel_radius\\\":3", "\\\"kernel_radius\\\":2.5", "kernel_radius"},
    {"\\\"kernel_radius\\\":3", "\\\"kernel_radios\\\":3", "kernel_radius"},
    {"\\\"kernel_hidden\\\":32", "\\\"kernel_hidden\\\":65", "kernel_hidden"},
    {"\\\"kernel_hidden\\\":32", "\\\"kernel_hidden\\\":\\\"32\\\"", "kernel_hidden"},
    {"\\\"out_channels\\\":52", "\\\"out_channels\\\":3", "out_channels must be 52"},
    {"\\\"arch\\\":\\\"kernel\\\"", "\\\"arch\\\":\\\"residual\\\"", "arch kernel only"},
    {"\\\"kernel_hidden\\\":32", "\\\"kernel_hidden\\\":8", "dec0.weight"},
    {"\"head.weight\"", "\"head.weights\"", "head.weight"},
    {"\"shape\":[52,56,1,1]", "\"shape\":[52,56,1]", "head.weight"},
  };
  for (size_t k = 0; k < sizeof edits / sizeof edits[0]; k++) {
    blob e = with_header_edit(&b, edits[k].from, edits[k].to);
    expect_reject(&e, HF_EFORMAT, edits[k].msg);
    free(e.data);
  }
  free(b.data);
  hf_weights_free(w);

  c.kernel_radius = 2, c.kernel_hidden = 0, c.out_channels = 25 + 3;
  assert_int_equal(hf_weights_init_random(&c, 6, &w), HF_OK);
  assert_null(w->head_w);
  assert_int_equal(hf_weights_save(path, w), HF_OK);
  assert_int_equal(hf_weights_load(path, &r, err, sizeof err), HF_OK);
  assert_int_equal(r->cfg.kernel_radius, 2);
  assert_int_equal(r->cfg.kernel_hidden, 0);
  assert_null(r->head_w);
  assert_int_equal(r->num_params, w->num_params);
  assert_memory_equal(r->storage, w->storage, w->num_params * sizeof(float));
  hf_weights_free(r);
  hf_weights_free(w);
  /* The kernel's keys on another architecture are a contradiction. */
  b = valid_file(NULL);
  blob u = with_header_edit(&b, "\\\"spp\\\"", "\\\"kernel_radius\\\":1,\\\"spp\\\"");
  expect_reject(&u, HF_EFORMAT, "arch kernel only");
  free(u.data);
  free(b.data);
}

static void test_missing_file(void **state) {
  hf_weights *w;
  char err[256] = "";
  assert_int_equal(hf_weights_load("/nonexistent/x.safetensors", &w, err, sizeof err), HF_EIO);
  assert_null(w);
  assert_non_null(strstr(err, "/nonexistent/x.safetensors"));
}

/* Files given for weights by mistake are named for what they are, where the
 * header length read off their first bytes said nothing to the user (a
 * PyTorch checkpoint, an EXR frame) or the size was "not supported" (a
 * directory, which fopen reads on Linux). */
static void test_not_weights(void **state) {
  unsigned char zip[64] = "PK\3\4 a checkpoint's zip archive";
  blob z = {zip, sizeof zip};
  expect_reject(&z, HF_EFORMAT, "a zip archive, not a safetensors file: a PyTorch checkpoint");
  expect_reject(&z, HF_EFORMAT, "--export W.safetensors");
  unsigned char exr[64] = {0x76, 0x2f, 0x31, 0x01, 2, 0, 0, 0};
  blob e = {exr, sizeof exr};
  expect_reject(&e, HF_EFORMAT, "an OpenEXR image, not a safetensors weights file");
  hf_weights *w;
  char err[512] = "";
  assert_int_equal(hf_weights_load(HF_TEST_DATA, &w, err, sizeof err), HF_EIO);
  assert_null(w);
  if (!strstr(err, "is a directory: give a .safetensors file"))
    fail_msg("error '%s' does not say it is a directory", err);
}

/* Random byte flips in the header: whatever happens, no crash, and either a
 * clean error or a successfully validated model. */
static void test_header_fuzz(void **state) {
  blob b = valid_file(NULL);
  uint64_t hl = hlen_of(&b);
  unsigned char *copy = malloc(b.len);
  srand(11);
  for (int it = 0; it < 3000; it++) {
    memcpy(copy, b.data, b.len);
    int flips = 1 + rand() % 4;
    for (int k = 0; k < flips; k++) copy[8 + rand() % hl] = (unsigned char)rand();
    hf_weights *w = NULL;
    char err[256] = "";
    int rc = hf_weights_load_mem(copy, b.len, &w, err, sizeof err);
    if (rc == HF_OK) {
      assert_non_null(w);
      assert_int_equal(hf_net_config_validate(&w->cfg), HF_OK);
      hf_weights_free(w);
    } else {
      assert_null(w);
      assert_true(err[0] != 0);
    }
  }
  free(copy);
  free(b.data);
}

static int setup(void **state) { return mkdtemp(tmpdir) ? 0 : -1; }
static int teardown(void **state) {
  char cmd[300];
  snprintf(cmd, sizeof cmd, "rm -rf '%s'", tmpdir);
  return system(cmd);
}

int main(void) {
  const struct CMUnitTest tests[] = {
    cmocka_unit_test(test_roundtrip_bit_exact),
      cmocka_unit_test(test_kernel_mix_metadata), cmocka_unit_test(test_truncated),
    cmocka_unit_test(test_save_replaces_whole),
    cmocka_unit_test(test_huge_header_length),  cmocka_unit_test(test_offsets_past_end),
    cmocka_unit_test(test_wrong_shapes),        cmocka_unit_test(test_bad_json),
    cmocka_unit_test(test_bad_dtype_and_tensor_set), cmocka_unit_test(test_missing_file),
    cmocka_unit_test(test_trailing_json),       cmocka_unit_test(test_checked_before_allocation),
    cmocka_unit_test(test_header_fuzz),         cmocka_unit_test(test_tiling_and_header_start), cmocka_unit_test(test_duplicate_keys),
    cmocka_unit_test(test_nonfinite_values),
    cmocka_unit_test(test_not_weights),         cmocka_unit_test(test_header_text),
    cmocka_unit_test(test_metadata_types),       cmocka_unit_test(test_kernel_arch),
  };
  return cmocka_run_group_tests(tests, setup, teardown);
}
