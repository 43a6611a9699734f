/* Codec unit tests: every message encoded and decoded back, and every
 * rejection path of every decoder. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "hfproto.h"

static uint8_t buf[1 << 16];

/* Decodes the header of buf and returns the payload pointer. */
static const uint8_t *split(const uint8_t *frame, int n, int type, hfp_header *h) {
  assert_true(n >= HFP_HEADER_SIZE);
  assert_int_equal(hfp_header_decode(frame, UINT32_MAX, h), 0);
  assert_int_equal(h->type, type);
  assert_int_equal(h->length, (uint32_t)(n - HFP_HEADER_SIZE));
  return frame + HFP_HEADER_SIZE;
}

static void test_header(void **state) {
  (void)state;
  hfp_header h = {HFP_FILTER, 0, 77, 1234}, d;
  uint8_t b[16];
  hfp_header_encode(&h, b);
  assert_memory_equal(b, "HFP1", 4);
  assert_int_equal(hfp_header_decode(b, 5000, &d), 0);
  assert_int_equal(d.type, HFP_FILTER);
  assert_int_equal(d.request_id, 77);
  assert_int_equal(d.length, 1234);
  /* over the receiver's limit: rejected but still decoded */
  assert_int_equal(hfp_header_decode(b, 1233, &d), -HFP_E_TOO_LARGE);
  assert_int_equal(d.request_id, 77);
  /* bad magic */
  b[0] ^= 1;
  assert_int_equal(hfp_header_decode(b, 5000, &d), -HFP_E_PROTOCOL);
  b[0] ^= 1;
  /* unknown types */
  h.type = 0;
  hfp_header_encode(&h, b);
  assert_int_equal(hfp_header_decode(b, 5000, &d), -HFP_E_PROTOCOL);
  h.type = HFP_TYPE_MAX + 1;
  hfp_header_encode(&h, b);
  assert_int_equal(hfp_header_decode(b, 5000, &d), -HFP_E_PROTOCOL);
  /* reserved flags */
  h.type = HFP_HELLO;
  h.flags = 1;
  hfp_header_encode(&h, b);
  assert_int_equal(hfp_header_decode(b, 5000, &d), -HFP_E_PROTOCOL);
}

/* m encoded into buf; its payload, the header in h. */
static const uint8_t *hello_payload(const hfp_hello *m, hfp_header *h) {
  int n = hfp_encode_hello(buf, sizeof buf, m);
  assert_true(n > 0);
  return split(buf, n, HFP_HELLO, h);
}

static void test_hello(void **state) {
  (void)state;
  hfp_hello m = {1, 3, "engine-7", "s3cret"}, d;
  hfp_header h;
  const uint8_t *p = hello_payload(&m, &h);
  int n;
  assert_int_equal(hfp_decode_hello(p, h.length, &d), 0);
  assert_int_equal(d.min_version, 1);
  assert_int_equal(d.max_version, 3);
  assert_string_equal(d.client_name, "engine-7");
  assert_string_equal(d.token, "s3cret");
  /* truncated, and trailing garbage */
  for (uint32_t len = 0; len < h.length; len++)
    assert_int_equal(hfp_decode_hello(p, len, &d), -HFP_E_LENGTH);
  uint8_t longer[256];
  memcpy(longer, p, h.length);
  longer[h.length] = 'x';
  assert_int_equal(hfp_decode_hello(longer, h.length + 1, &d), -HFP_E_LENGTH);
  /* no token is fine */
  m.token[0] = 0;
  n = hfp_encode_hello(buf, sizeof buf, &m);
  p = split(buf, n, HFP_HELLO, &h);
  assert_int_equal(hfp_decode_hello(p, h.length, &d), 0);
  assert_string_equal(d.token, "");
  /* control byte in the name */
  memcpy(longer, p, h.length);
  longer[8] = '\n';
  assert_int_equal(hfp_decode_hello(longer, h.length, &d), -HFP_E_INVALID);
  /* empty name */
  memcpy(longer, p, h.length);
  hfp_put_u16(longer + 4, 0);
  assert_int_equal(hfp_decode_hello(longer, 8, &d), -HFP_E_INVALID);
  /* name length over the maximum */
  hfp_put_u16(longer + 4, HFP_NAME_MAX + 1);
  assert_int_equal(hfp_decode_hello(longer, h.length, &d), -HFP_E_INVALID);
  /* versions inverted */
  memcpy(longer, p, h.length);
  hfp_put_u16(longer, 4);
  assert_int_equal(hfp_decode_hello(longer, h.length, &d), -HFP_E_VERSION);
  /* a range that starts below version 1 still holds it: 0..1 gets 1 */
  memcpy(longer, p, h.length);
  hfp_put_u16(longer, 0);
  hfp_put_u16(longer + 2, 1);
  assert_int_equal(hfp_decode_hello(longer, h.length, &d), 0);
  assert_int_equal(hfp_negotiate(d.min_version, d.max_version), 1);
  hfp_hello zero_one = {0, 1, "old-client", ""};
  assert_true(hfp_encode_hello(buf, sizeof buf, &zero_one) > 0);
  /* ...but 0..0 holds no version at all */
  hfp_put_u16(longer + 2, 0);
  assert_int_equal(hfp_decode_hello(longer, h.length, &d), -HFP_E_VERSION);
  /* the encoder refuses what the decoder would */
  hfp_hello none = {0, 0, "x", ""};
  assert_int_equal(hfp_encode_hello(buf, sizeof buf, &none), -HFP_E_INVALID);
  hfp_hello bad = {2, 1, "x", ""};
  assert_int_equal(hfp_encode_hello(buf, sizeof buf, &bad), -HFP_E_INVALID);
  hfp_hello spaced = {1, 1, "has space", ""};
  assert_int_equal(hfp_encode_hello(buf, sizeof buf, &spaced), -HFP_E_INVALID);
  assert_int_equal(hfp_encode_hello(buf, 10, &m), -HFP_E_NOSPACE);
  /* negotiation */
  assert_int_equal(hfp_negotiate(1, 1), 1);
  assert_int_equal(hfp_negotiate(1, 9), HFP_VERSION);
  assert_int_equal(hfp_negotiate(HFP_VERSION + 1, 9), -HFP_E_VERSION);
  assert_int_equal(hfp_negotiate(0, 0), -HFP_E_VERSION);
  assert_int_equal(hfp_negotiate(0, 1), 1);
  assert_int_equal(hfp_negotiate(0, 65535), HFP_VERSION);
  assert_int_equal(hfp_negotiate(3, 2), -HFP_E_VERSION);
}

/* A malformed HELLO's refusal names the field at fault and what it must
 * be, and never copies the token's bytes. */
static void test_hello_fault(void **state) {
  (void)state;
  hfp_hello m = {1, 4, "engine-7", "s3cret"}, d;
  hfp_header h;
  const uint8_t *p = hello_payload(&m, &h);
  uint8_t q[512];
  char why[192];
  struct {
    const char *what;
    int set_name_len, set_token_len, poke_at, poke, len_delta;
    const char *words;
  } cases[] = {
      {"name_len 0", 0, -1, -1, 0, 0, "name_len 0 is outside 1..64"},
      {"name_len 65", 65, -1, -1, 0, 0, "name_len 65 is outside 1..64"},
      {"token_len 257", -1, 257, -1, 0, 0, "token_len 257 is outside 0..256"},
      {"space in the name", -1, -1, 8 + 3, ' ', 0, "client name byte 3 is 0x20"},
      {"DEL in the name", -1, -1, 8, 0x7f, 0, "client name byte 0 is 0x7f"},
      {"NUL in the token", -1, -1, 8 + 8 + 2, 0, 0, "auth token byte 2 is outside"},
      {"one byte missing", -1, -1, -1, 0, -1, "ends inside the 6-byte auth token"},
      {"one byte trailing", -1, -1, -1, 0, 1, "the payload is 23 bytes but its fields"},
  };
  for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
    memcpy(q, p, h.length);
    q[h.length] = 'x';
    if (cases[i].set_name_len >= 0) hfp_put_u16(q + 4, (uint16_t)cases[i].set_name_len);
    if (cases[i].set_token_len >= 0) hfp_put_u16(q + 6, (uint16_t)cases[i].set_token_len);
    if (cases[i].poke_at >= 0) q[cases[i].poke_at] = (uint8_t)cases[i].poke;
    size_t len = (size_t)((int)h.length + cases[i].len_delta);
    int rc = hfp_decode_hello(q, len, &d);
    assert_true(rc == -HFP_E_LENGTH || rc == -HFP_E_INVALID);
    hfp_hello_fault(q, len, rc, why, sizeof why);
    if (!strstr(why, cases[i].words)) fail_msg("%s: \"%s\" lacks \"%s\"", cases[i].what, why,
                                               cases[i].words);
    assert_null(strstr(why, "s3c"));
  }
  /* shorter than the fixed fields; and a buffer too small still ends in NUL */
  hfp_hello_fault(p, 5, -HFP_E_LENGTH, why, sizeof why);
  assert_non_null(strstr(why, "shorter than its 8 fixed bytes"));
  hfp_hello_fault(p, 5, -HFP_E_LENGTH, why, 4);
  assert_int_equal(strlen(why), 3);
}

/* One URL grammar for both sides (PROTOCOL.md, "Addresses"). */
static void test_url(void **state) {
  (void)state;
  hfp_url u;
  char why[256];
  assert_int_equal(hfp_url_parse("unix:/run/hf.sock", 0, &u, why, sizeof why), 0);
  assert_int_equal(u.kind, HFP_URL_UNIX);
  assert_string_equal(u.path, "/run/hf.sock");
  assert_int_equal(hfp_url_parse("tcp:10.1.2.3:7070", 0, &u, why, sizeof why), 0);
  assert_int_equal(u.kind, HFP_URL_TCP);
  assert_string_equal(u.host, "10.1.2.3");
  assert_int_equal(u.port, 7070);
  assert_int_equal(hfp_url_parse("tcp:gpu-box.local:1", 0, &u, why, sizeof why), 0);
  assert_string_equal(u.host, "gpu-box.local");
  assert_int_equal(u.port, 1);
  assert_int_equal(hfp_url_parse("tcp:65535", 0, &u, why, sizeof why), 0);
  assert_string_equal(u.host, "127.0.0.1");
  assert_int_equal(u.port, 65535);
  assert_int_equal(hfp_url_parse("tcp:[::1]:7070", 0, &u, why, sizeof why), 0);
  assert_string_equal(u.host, "::1");
  assert_int_equal(u.port, 7070);
  assert_int_equal(hfp_url_parse("tcp:[fe80::1%eth0]:80", 0, &u, why, sizeof why), 0);
  assert_string_equal(u.host, "fe80::1%eth0");
  assert_int_equal(u.tls, 0);
  /* tls: is TCP with the same grammar, and TLS on top */
  assert_int_equal(hfp_url_parse("tls:render-07.farm:7443", 0, &u, why, sizeof why), 0);
  assert_int_equal(u.kind, HFP_URL_TCP);
  assert_int_equal(u.tls, 1);
  assert_string_equal(u.host, "render-07.farm");
  assert_int_equal(u.port, 7443);
  assert_int_equal(hfp_url_parse("tls:[::1]:7443", 0, &u, why, sizeof why), 0);
  assert_int_equal(u.tls, 1);
  assert_string_equal(u.host, "::1");
  assert_int_equal(hfp_url_parse("tls:7443", 0, &u, why, sizeof why), 0);
  assert_string_equal(u.host, "127.0.0.1");
  assert_int_equal(u.tls, 1);
  /* port 0 only where it means "any free port" */
  assert_int_equal(hfp_url_parse("tcp:127.0.0.1:0", HFP_URL_LISTEN, &u, why, sizeof why), 0);
  assert_int_equal(u.port, 0);
  /* and the range a refusal names is the one that applies */
  assert_int_equal(hfp_url_parse("tcp:127.0.0.1:99999", 0, &u, why, sizeof why), -HFP_E_INVALID);
  assert_non_null(strstr(why, "port 99999 is outside 1..65535"));
  assert_int_equal(hfp_url_parse("tcp:127.0.0.1:99999", HFP_URL_LISTEN, &u, why, sizeof why),
                   -HFP_E_INVALID);
  assert_non_null(strstr(why, "port 99999 is outside 0..65535"));
  static const struct {
    const char *url, *says;
  } bad[] = {
    {"tcp:127.0.0.1:0", "port 0 is outside 1..65535"},
    {"tcp:127.0.0.1:65536", "port 65536 is outside 0..65535"},
    {"tcp:127.0.0.1:99999999999999999999", "is outside 0..65535"},
    {"tcp:70000", "port 70000 is outside 0..65535"},
    {"tcp:127.0.0.1:80x", "port '80x' is not a decimal number"},
    {"tcp:127.0.0.1:-1", "port '-1' is not a decimal number"},
    {"tcp:127.0.0.1:+80", "port '+80' is not a decimal number"},
    {"tcp:127.0.0.1: 80", "is not a decimal number"},
    {"tcp:127.0.0.1:80 ", "is not a decimal number"},
    {"tcp:127.0.0.1:", "no port"},
    {"tcp:", "no port"},
    {"tcp::80", "empty host"},
    {"tcp:::1:80", "brackets"},
    {"tcp:[::1]80", "want [ADDRESS]:PORT"},
    {"tcp:[::1", "without ']'"},
    {"tcp:[]:80", "empty IPv6 address"},
    {"tcp:[::g]:80", "'g' in an IPv6 address"},
    {"tcp:host name:80", "' ' in the host name"},
    {"tcp:nohostport", "is not a decimal number"},
    {"unix:", "empty socket path"},
    {"tls:127.0.0.1:65536", "port 65536 is outside 0..65535"},
    {"tls:host name:80", "' ' in the host name"},
    {"tls://host:7443", "no '//' after 'tls:': write tls:HOST:PORT"},
    {"tcp://host:7070", "no '//' after 'tcp:': write tcp:HOST:PORT"},
    {"tls:", "no port"},
    {"http://x", "want unix:PATH"},
    {"", "want unix:PATH"},
  };
  for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++) {
    int rc = hfp_url_parse(bad[i].url, HFP_URL_LISTEN * (i > 0), &u, why, sizeof why);
    if (rc != -HFP_E_INVALID || !strstr(why, bad[i].says) || !strstr(why, "bad URL '"))
      fail_msg("'%s': rc %d, '%s' (want '%s')", bad[i].url, rc, why, bad[i].says);
  }
  char path[200];
  memset(path, 'a', sizeof path);
  memcpy(path, "unix:", 5);
  path[sizeof path - 1] = 0;
  assert_int_equal(hfp_url_parse(path, 0, &u, why, sizeof why), -HFP_E_INVALID);
  assert_non_null(strstr(why, "socket path longer than"));
  /* why may be NULL */
  assert_int_equal(hfp_url_parse("tcp:1:2:3", 0, &u, NULL, 0), -HFP_E_INVALID);
}

static hfp_hello_ok sample_hello_ok(void) {
  hfp_hello_ok m;
  memset(&m, 0, sizeof m);
  m.version = 1;
  m.server_flags = HFP_SERVER_AUTH_REQUIRED;
  m.max_width = 4096;
  m.max_height = 2160;
  m.max_spp = 8;
  m.max_inflight = 32;
  m.dtypes = HFP_DTYPE_MASK_ALL;
  m.max_batch = 4;
  m.queue_size = 64;
  m.max_frame_bytes = 1ull << 33;
  strcpy(m.server_name, "hairfilterd/0.1");
  return m;
}

static void test_hello_ok(void **state) {
  (void)state;
  hfp_hello_ok m = sample_hello_ok(), d;
  int n = hfp_encode_hello_ok(buf, sizeof buf, &m);
  assert_true(n > 0);
  hfp_header h;
  const uint8_t *p = split(buf, n, HFP_HELLO_OK, &h);
  assert_int_equal(hfp_decode_hello_ok(p, h.length, &d), 0);
  assert_memory_equal(&m, &d, sizeof m);
  for (uint32_t len = 0; len < h.length; len++)
    assert_int_equal(hfp_decode_hello_ok(p, len, &d), -HFP_E_LENGTH);
  uint8_t c[256];
  memcpy(c, p, h.length);
  hfp_put_u16(c, HFP_VERSION + 1);  /* a version this codec does not speak */
  assert_int_equal(hfp_decode_hello_ok(c, h.length, &d), -HFP_E_VERSION);
  memcpy(c, p, h.length);
  hfp_put_u16(c + 12, 0);  /* max_spp */
  assert_int_equal(hfp_decode_hello_ok(c, h.length, &d), -HFP_E_INVALID);
  memcpy(c, p, h.length);
  hfp_put_u32(c + 16, 4);  /* dtypes: an unknown bit */
  assert_int_equal(hfp_decode_hello_ok(c, h.length, &d), -HFP_E_INVALID);
  m.max_spp = 17;
  assert_int_equal(hfp_encode_hello_ok(buf, sizeof buf, &m), -HFP_E_INVALID);
}

/* Version 2 appends the server's software version to HELLO_OK; a
 * version-1 peer gets the version-1 frame, byte for byte. */
static void test_hello_ok_software(void **state) {
  (void)state;
  hfp_hello_ok m = sample_hello_ok(), d;
  strcpy(m.software_version, "0.1.0");
  m.version = 1;
  int n1 = hfp_encode_hello_ok(buf, sizeof buf, &m);
  hfp_header h;
  const uint8_t *p = split(buf, n1, HFP_HELLO_OK, &h);
  assert_int_equal(hfp_decode_hello_ok(p, h.length, &d), 0);
  assert_string_equal(d.software_version, "");   /* not on a version-1 wire */
  uint8_t c[256];
  memcpy(c, p, h.length);
  c[h.length] = 0;                      /* a version-1 frame with a byte more */
  assert_int_equal(hfp_decode_hello_ok(c, h.length + 1, &d), -HFP_E_LENGTH);

  m.version = 2;
  int n2 = hfp_encode_hello_ok(buf, sizeof buf, &m);
  assert_int_equal(n2, n1 + 1 + 5);
  p = split(buf, n2, HFP_HELLO_OK, &h);
  assert_int_equal(hfp_decode_hello_ok(p, h.length, &d), 0);
  assert_string_equal(d.software_version, "0.1.0");
  assert_string_equal(d.server_name, m.server_name);
  for (uint32_t len = h.length - 6 + 1; len < h.length; len++)
    assert_int_equal(hfp_decode_hello_ok(p, len, &d), -HFP_E_LENGTH);
  /* A version-2 server that says nothing after its name is read as one
   * that does not give its version. */
  assert_int_equal(hfp_decode_hello_ok(p, h.length - 6, &d), 0);
  assert_string_equal(d.software_version, "");
  memcpy(c, p, h.length);
  c[h.length - 3] = ' ';                /* no spaces in a version */
  assert_int_equal(hfp_decode_hello_ok(c, h.length, &d), -HFP_E_INVALID);
  memcpy(c, p, h.length);
  c[h.length - 6] = 65;                 /* over 64 bytes */
  assert_int_equal(hfp_decode_hello_ok(c, h.length, &d), -HFP_E_INVALID);
  /* An empty one is a length byte of 0. */
  m.software_version[0] = 0;
  assert_int_equal(hfp_encode_hello_ok(buf, sizeof buf, &m), n1 + 1);
  strcpy(m.software_version, "0.1 beta");
  assert_int_equal(hfp_encode_hello_ok(buf, sizeof buf, &m), -HFP_E_INVALID);
  /* The largest frame fits HFP_HELLO_OK_MAX. */
  memset(m.server_name, 'n', HFP_NAME_MAX);
  m.server_name[HFP_NAME_MAX] = 0;
  memset(m.software_version, 'v', HFP_NAME_MAX);
  m.software_version[HFP_NAME_MAX] = 0;
  assert_int_equal(hfp_encode_hello_ok(buf, sizeof buf, &m), HFP_HELLO_OK_MAX);
}

static void test_empty(void **state) {
  (void)state;
  hfp_header h;
  int n = hfp_encode_empty(buf, sizeof buf, HFP_LIST_VARIANTS, 5);
  assert_int_equal(n, HFP_HEADER_SIZE);
  split(buf, n, HFP_LIST_VARIANTS, &h);
  assert_int_equal(h.request_id, 5);
  n = hfp_encode_empty(buf, sizeof buf, HFP_STATS, 0);
  split(buf, n, HFP_STATS, &h);
  assert_int_equal(hfp_encode_empty(buf, sizeof buf, HFP_FILTER, 1), -HFP_E_INVALID);
  assert_int_equal(hfp_encode_empty(buf, 15, HFP_STATS, 1), -HFP_E_NOSPACE);
}

static void test_variants(void **state) {
  (void)state;
  hfp_variant v[2];
  memset(v, 0, sizeof v);
  strcpy(v[0].name, "Base");
  strcpy(v[0].backend, "cpu-ref");
  strcpy(v[0].precision, "fp32");
  v[0].spp = 4;
  v[0].num_levels = 5;
  for (int i = 0; i < 5; i++) v[0].levels[i] = 16u << i;
  strcpy(v[1].name, "Small@1spp");
  strcpy(v[1].backend, "cudnn");
  strcpy(v[1].precision, "fp16");
  v[1].spp = 1;
  v[1].num_levels = 1;
  v[1].levels[0] = 8;
  int n = hfp_encode_variants(buf, sizeof buf, v, 2);
  assert_int_equal((size_t)n, hfp_frame_size_variants(v, 2));
  hfp_header h;
  const uint8_t *p = split(buf, n, HFP_VARIANTS, &h);
  hfp_variant d[HFP_MAX_VARIANTS];
  int count = -1;
  assert_int_equal(hfp_decode_variants(p, h.length, d, HFP_MAX_VARIANTS, &count), 0);
  assert_int_equal(count, 2);
  assert_memory_equal(&v[0], &d[0], sizeof v[0]);
  assert_memory_equal(&v[1], &d[1], sizeof v[1]);
  for (uint32_t len = 0; len < h.length; len++)
    assert_int_not_equal(hfp_decode_variants(p, len, d, HFP_MAX_VARIANTS, &count), 0);
  assert_int_equal(hfp_decode_variants(p, h.length, d, 1, &count), -HFP_E_NOSPACE);
  uint8_t c[1024];
  memcpy(c, p, h.length);
  hfp_put_u16(c, HFP_MAX_VARIANTS + 1);
  assert_int_equal(hfp_decode_variants(c, h.length, d, HFP_MAX_VARIANTS, &count),
                   -HFP_E_INVALID);
  /* entry 0 levels field: 2 + (1+4) + (1+7) + (1+4) + 2 = 21 */
  memcpy(c, p, h.length);
  hfp_put_u16(c + 21, 9);
  assert_int_equal(hfp_decode_variants(c, h.length, d, HFP_MAX_VARIANTS, &count),
                   -HFP_E_INVALID);
  memcpy(c, p, h.length);
  hfp_put_u16(c + 19, 0);  /* spp 0 */
  assert_int_equal(hfp_decode_variants(c, h.length, d, HFP_MAX_VARIANTS, &count),
                   -HFP_E_INVALID);
  v[0].num_levels = 0;
  assert_int_equal(hfp_encode_variants(buf, sizeof buf, v, 2), -HFP_E_INVALID);
  assert_int_equal(hfp_encode_variants(buf, sizeof buf, v, HFP_MAX_VARIANTS + 1),
                   -HFP_E_INVALID);
  /* an empty list is valid */
  n = hfp_encode_variants(buf, sizeof buf, v, 0);
  p = split(buf, n, HFP_VARIANTS, &h);
  assert_int_equal(hfp_decode_variants(p, h.length, d, HFP_MAX_VARIANTS, &count), 0);
  assert_int_equal(count, 0);
}

static hfp_filter sample_filter(const float *data, uint32_t w, uint32_t hgt, uint16_t spp) {
  hfp_filter m;
  memset(&m, 0, sizeof m);
  strcpy(m.variant, "Base");
  m.flags = HFP_FILTER_COMPOSITE;
  m.width = w;
  m.height = hgt;
  m.spp = spp;
  m.in_dtype = HFP_F32;
  m.out_dtype = HFP_F16;
  for (int i = 0; i < 3; i++) {
    m.hair[i] = 0.1f * (float)(i + 1);
    m.light[i] = 1.0f;
    m.bg[i] = 0.5f;
  }
  m.data = data;
  m.data_len = (uint64_t)w * hgt * spp * 6 * 4;
  return m;
}

static void test_filter(void **state) {
  (void)state;
  enum { W = 3, H = 2, S = 2 };
  float data[W * H * S * 6];
  for (int i = 0; i < W * H * S * 6; i++) data[i] = (float)i * 0.5f;
  hfp_filter m = sample_filter(data, W, H, S), d;
  uint64_t total = 0;
  int n = hfp_encode_filter_head(buf, sizeof buf, 42, &m, &total);
  assert_int_equal(n, HFP_HEADER_SIZE + HFP_FILTER_FIXED + 4);
  assert_int_equal(total, (uint64_t)n + sizeof data);
  memcpy(buf + n, data, sizeof data);
  hfp_header h;
  const uint8_t *p = split(buf, (int)total, HFP_FILTER, &h);
  assert_int_equal(h.request_id, 42);
  assert_int_equal(hfp_decode_filter(p, h.length, &d), 0);
  assert_string_equal(d.variant, "Base");
  assert_int_equal(d.flags, HFP_FILTER_COMPOSITE);
  assert_int_equal(d.width, W);
  assert_int_equal(d.height, H);
  assert_int_equal(d.spp, S);
  assert_int_equal(d.in_dtype, HFP_F32);
  assert_int_equal(d.out_dtype, HFP_F16);
  assert_memory_equal(d.hair, m.hair, sizeof m.hair);
  assert_memory_equal(d.bg, m.bg, sizeof m.bg);
  assert_int_equal(d.data_len, sizeof data);
  assert_memory_equal(d.data, data, sizeof data);

  /* head alone, incrementally: NOSPACE until the fixed part is in */
  size_t head = 0;
  for (size_t avail = 0; avail < HFP_FILTER_FIXED + 4; avail++)
    assert_int_equal(hfp_decode_filter_head(p, avail, h.length, &d, &head),
                     -HFP_E_NOSPACE);
  assert_int_equal(hfp_decode_filter_head(p, HFP_FILTER_FIXED + 4, h.length, &d, &head), 0);
  assert_int_equal(head, HFP_FILTER_FIXED + 4);
  assert_null(d.data);
  assert_int_equal(d.data_len, sizeof data);

  /* every shorter or longer payload is a length mismatch */
  for (uint32_t len = 0; len < h.length; len++)
    assert_int_equal(hfp_decode_filter(p, len, &d), -HFP_E_LENGTH);
  static uint8_t c[4096];
  memcpy(c, p, h.length);
  assert_int_equal(hfp_decode_filter(c, h.length + 1, &d), -HFP_E_LENGTH);

  /* Each fault's code, and the name as the decoder leaves it: read for a
   * fault after it (so a server can charge the variant), empty otherwise. */
#define MUTATE(stmt, want, name)                                   \
  do {                                                             \
    memcpy(c, p, h.length);                                        \
    stmt;                                                          \
    assert_int_equal(hfp_decode_filter(c, h.length, &d), (want)); \
    assert_string_equal(d.variant, (name));                        \
  } while (0)
  MUTATE(hfp_put_u16(c + 0, 0), -HFP_E_INVALID, "");                /* empty variant */
  MUTATE(hfp_put_u16(c + 0, HFP_NAME_MAX + 1), -HFP_E_INVALID, "");
  MUTATE(hfp_put_u16(c + 0, 5), -HFP_E_INVALID, "");     /* variant eats a data byte: 0.0f */
  MUTATE(c[HFP_FILTER_FIXED] = 0x01, -HFP_E_INVALID, ""); /* control char in name */
  MUTATE(hfp_put_u16(c + 2, 0x0100), -HFP_E_UNSUPPORTED, "Base");      /* unknown flag */
  MUTATE(hfp_put_u32(c + 4, 0), -HFP_E_INVALID, "Base");               /* width 0 */
  MUTATE(hfp_put_u32(c + 8, HFP_MAX_SIDE + 1), -HFP_E_INVALID, "Base");
  MUTATE(hfp_put_u32(c + 4, 4), -HFP_E_LENGTH, "Base");                /* dims vs payload */
  MUTATE(hfp_put_u16(c + 12, 0), -HFP_E_INVALID, "Base");              /* spp 0 */
  MUTATE(hfp_put_u16(c + 12, HFP_MAX_SPP + 1), -HFP_E_INVALID, "Base");
  MUTATE(hfp_put_u16(c + 12, 1), -HFP_E_LENGTH, "Base");
  MUTATE(c[14] = 2, -HFP_E_UNSUPPORTED, "Base");                       /* in dtype */
  MUTATE(c[15] = 9, -HFP_E_UNSUPPORTED, "Base");                       /* out dtype */
  MUTATE(c[14] = HFP_F16, -HFP_E_LENGTH, "Base");                      /* half the bytes */
  MUTATE(hfp_put_u32(c + 16, 0x7fc00000u), -HFP_E_INVALID, "Base");    /* NaN colour */
  MUTATE(hfp_put_u32(c + 48, 0x7f800000u), -HFP_E_INVALID, "Base");    /* inf background */
#undef MUTATE

  /* f16 in: half the bytes */
  m.in_dtype = HFP_F16;
  m.data_len /= 2;
  n = hfp_encode_filter_head(buf, sizeof buf, 43, &m, &total);
  assert_true(n > 0);
  assert_int_equal(total, (uint64_t)n + sizeof data / 2);

  /* the encoder refuses inconsistent requests */
  m.data_len += 1;
  assert_int_equal(hfp_encode_filter_head(buf, sizeof buf, 1, &m, &total), -HFP_E_INVALID);
  m.data_len -= 1;
  assert_int_equal(hfp_encode_filter_head(buf, sizeof buf, 0, &m, &total), -HFP_E_INVALID);
  m.in_dtype = 7;
  assert_int_equal(hfp_encode_filter_head(buf, sizeof buf, 1, &m, &total),
                   -HFP_E_UNSUPPORTED);
  m.in_dtype = HFP_F16;
  assert_int_equal(hfp_encode_filter_head(buf, 20, 1, &m, &total), -HFP_E_NOSPACE);
  /* the largest frame the codec accepts still has a 64-bit size */
  uint64_t big;
  assert_int_equal(hfp_features_bytes(HFP_MAX_SIDE, HFP_MAX_SIDE, HFP_MAX_SPP, HFP_F32, &big), 0);
  assert_int_equal(big, (uint64_t)HFP_MAX_SIDE * HFP_MAX_SIDE * HFP_MAX_SPP * 24);
  assert_int_equal(hfp_output_bytes(2, 2, 5, HFP_F32, &big), -HFP_E_INVALID);
}

static void test_result(void **state) {
  (void)state;
  enum { W = 4, H = 3 };
  uint16_t data[W * H * 3], rgba[W * H * 4];
  for (int i = 0; i < W * H * 3; i++) data[i] = (uint16_t)i;
  for (int i = 0; i < W * H * 4; i++) rgba[i] = (uint16_t)(1000 + i);
  hfp_result m;
  memset(&m, 0, sizeof m);
  m.dtype = HFP_F16;
  m.flags = HFP_FILTER_COMPOSITE;
  m.width = W;
  m.height = H;
  m.batch = 3;
  m.timing = (hfp_timing){10, 20, 30, 40, 150};
  m.data = data;
  m.data_len = sizeof data;
  m.rgba = rgba;
  m.rgba_len = sizeof rgba;
  uint64_t total;
  int n = hfp_encode_result_head(buf, sizeof buf, 9, &m, &total);
  assert_int_equal(n, HFP_RESULT_HEAD_MAX);
  assert_int_equal(total, (uint64_t)n + sizeof data + sizeof rgba);
  memcpy(buf + n, data, sizeof data);
  memcpy(buf + n + sizeof data, rgba, sizeof rgba);
  hfp_header h;
  const uint8_t *p = split(buf, (int)total, HFP_RESULT, &h);
  assert_int_equal(h.request_id, 9);
  hfp_result d;
  assert_int_equal(hfp_decode_result(p, h.length, &d), 0);
  assert_int_equal(d.status, 0);
  assert_int_equal(d.batch, 3);
  assert_int_equal(d.timing.queue_us, 10);
  assert_int_equal(d.timing.input_us, 20);
  assert_int_equal(d.timing.infer_us, 30);
  assert_int_equal(d.timing.output_us, 40);
  assert_int_equal(d.timing.total_us, 150);
  assert_memory_equal(d.data, data, sizeof data);
  assert_memory_equal(d.rgba, rgba, sizeof rgba);
  /* head decoding before the tensors arrive */
  assert_int_equal(hfp_decode_result_head(p, HFP_RESULT_FIXED - 1, h.length, &d),
                   -HFP_E_NOSPACE);
  assert_int_equal(hfp_decode_result_head(p, HFP_RESULT_FIXED, h.length, &d), 0);
  assert_int_equal(d.rgba_len, sizeof rgba);
  for (uint32_t len = 0; len < h.length; len++)
    assert_int_equal(hfp_decode_result(p, len, &d), -HFP_E_LENGTH);
  static uint8_t c[4096];
  memcpy(c, p, h.length);
  c[3] = 0;  /* no composite flag: the rgba bytes are now excess */
  assert_int_equal(hfp_decode_result(c, h.length, &d), -HFP_E_LENGTH);
  memcpy(c, p, h.length);
  c[2] = 5;  /* dtype */
  assert_int_equal(hfp_decode_result(c, h.length, &d), -HFP_E_UNSUPPORTED);
  memcpy(c, p, h.length);
  c[3] = 0x80;  /* unknown flag */
  assert_int_equal(hfp_decode_result(c, h.length, &d), -HFP_E_INVALID);
  memcpy(c, p, h.length);
  hfp_put_u32(c + 12, 0);  /* batch 0 */
  assert_int_equal(hfp_decode_result(c, h.length, &d), -HFP_E_INVALID);

  /* a failed request: status, no tensors */
  hfp_result f;
  memset(&f, 0, sizeof f);
  f.status = HFP_E_SHUTTING_DOWN;
  f.timing.queue_us = 5;
  f.timing.total_us = 6;
  n = hfp_encode_result_head(buf, sizeof buf, 10, &f, &total);
  assert_int_equal(total, (uint64_t)n);
  p = split(buf, n, HFP_RESULT, &h);
  assert_int_equal(hfp_decode_result(p, h.length, &d), 0);
  assert_int_equal(d.status, HFP_E_SHUTTING_DOWN);
  assert_null(d.data);
  memcpy(c, p, h.length);
  hfp_put_u32(c + 4, 2);  /* a failure with dimensions */
  assert_int_equal(hfp_decode_result(c, h.length, &d), -HFP_E_INVALID);
  f.width = 1;
  assert_int_equal(hfp_encode_result_head(buf, sizeof buf, 10, &f, &total), -HFP_E_INVALID);
  m.data_len--;
  assert_int_equal(hfp_encode_result_head(buf, sizeof buf, 9, &m, &total), -HFP_E_INVALID);
}

static void test_error(void **state) {
  (void)state;
  hfp_error m = {HFP_E_UNKNOWN_VARIANT, 0, "unknown variant 'Huge'"}, d;
  int n = hfp_encode_error(buf, sizeof buf, 12, &m);
  hfp_header h;
  const uint8_t *p = split(buf, n, HFP_ERROR, &h);
  assert_int_equal(h.request_id, 12);
  assert_int_equal(hfp_decode_error(p, h.length, &d), 0);
  assert_int_equal(d.code, HFP_E_UNKNOWN_VARIANT);
  assert_int_equal(d.fatal, 0);
  assert_string_equal(d.message, m.message);
  for (uint32_t len = 0; len < h.length; len++)
    assert_int_equal(hfp_decode_error(p, len, &d), -HFP_E_LENGTH);
  uint8_t c[512];
  memcpy(c, p, h.length);
  hfp_put_u32(c, 0);
  assert_int_equal(hfp_decode_error(c, h.length, &d), -HFP_E_INVALID);
  memcpy(c, p, h.length);
  c[4] = 2;
  assert_int_equal(hfp_decode_error(c, h.length, &d), -HFP_E_INVALID);
  memcpy(c, p, h.length);
  c[5] = 1;
  assert_int_equal(hfp_decode_error(c, h.length, &d), -HFP_E_INVALID);
  memcpy(c, p, h.length);
  c[10] = 0x1b;  /* escape in the message */
  assert_int_equal(hfp_decode_error(c, h.length, &d), -HFP_E_INVALID);
  memcpy(c, p, h.length);
  hfp_put_u32(c, 999);  /* a code from a newer server is kept */
  assert_int_equal(hfp_decode_error(c, h.length, &d), 0);
  assert_int_equal(d.code, 999);
  hfp_error bad = {HFP_E_NOSPACE, 0, "local only"};
  assert_int_equal(hfp_encode_error(buf, sizeof buf, 1, &bad), -HFP_E_INVALID);
  bad.code = 0;
  assert_int_equal(hfp_encode_error(buf, sizeof buf, 1, &bad), -HFP_E_INVALID);
  /* every code has a name */
  for (int i = 0; i < HFP_E_COUNT; i++) {
    assert_non_null(hfp_strerror(i));
    assert_string_equal(hfp_strerror(i), hfp_strerror(-i));
  }
  assert_string_equal(hfp_strerror(4242), "unknown protocol error");
  assert_string_equal(hfp_code_name(HFP_E_BUSY), "BUSY");
  assert_string_equal(hfp_code_name(-HFP_E_UNKNOWN_VARIANT), "UNKNOWN_VARIANT");
  assert_string_equal(hfp_code_name(HFP_E_SHUTTING_DOWN), "SHUTTING_DOWN");
  assert_string_equal(hfp_code_name(99), "UNKNOWN");
}

static void test_stats(void **state) {
  (void)state;
  static hfp_stats m, d;
  memset(&m, 0, sizeof m);
  m.uptime_us = 123456789;
  m.connections_total = 17;
  m.connections_open = 2;
  m.queue_depth = 3;
  m.queue_capacity = 64;
  m.protocol_errors = 4;
  m.num_variants = 2;
  strcpy(m.variants[0].name, "Base");
  strcpy(m.variants[1].name, "Small");
  for (int v = 0; v < 2; v++) {
    m.variants[v].requests_ok = 100 + v;
    m.variants[v].requests_failed = 2;
    m.variants[v].rejected = 5;
    m.variants[v].batches = 50;
    m.variants[v].sum_queue_us = 1000;
    m.variants[v].sum_infer_us = 2000;
    m.variants[v].sum_total_us = 4000;
    for (int b = 0; b < HFP_HIST_BUCKETS; b++) {
      m.variants[v].hist_total[b] = (uint64_t)b * 3 + v;
      m.variants[v].hist_infer[b] = (uint64_t)b;
    }
  }
  int n = hfp_encode_stats(buf, sizeof buf, &m);
  assert_int_equal((size_t)n, hfp_frame_size_stats(&m));
  hfp_header h;
  const uint8_t *p = split(buf, n, HFP_STATS_REPLY, &h);
  assert_int_equal(hfp_decode_stats(p, h.length, &d), 0);
  assert_memory_equal(&m, &d, sizeof m);
  for (uint32_t len = 0; len < h.length; len += 7)
    assert_int_equal(hfp_decode_stats(p, len, &d), -HFP_E_LENGTH);
  static uint8_t c[8192];
  memcpy(c, p, h.length);
  hfp_put_u16(c + 38, HFP_HIST_BUCKETS - 1);
  assert_int_equal(hfp_decode_stats(c, h.length, &d), -HFP_E_INVALID);
  memcpy(c, p, h.length);
  hfp_put_u16(c + 36, HFP_MAX_VARIANTS + 1);
  assert_int_equal(hfp_decode_stats(c, h.length, &d), -HFP_E_INVALID);
  m.num_variants = HFP_MAX_VARIANTS + 1;
  assert_int_equal(hfp_encode_stats(buf, sizeof buf, &m), -HFP_E_INVALID);
}

/* Two plain variants, V0 and V1 (4 spp, one level of 8 channels), for the
 * VARIANTS blocks of versions 2 and 3. */
static void two_variants(hfp_variant v[2]) {
  memset(v, 0, 2 * sizeof *v);
  for (int i = 0; i < 2; i++) {
    snprintf(v[i].name, sizeof v[i].name, "V%d", i);
    strcpy(v[i].backend, "cpu");
    strcpy(v[i].precision, "fp32");
    v[i].spp = 4;
    v[i].num_levels = 1;
    v[i].levels[0] = 8;
  }
}

/* Version 2 (PROTOCOL.md, "Version 2"): negotiation, the RESULT flag, the
 * ranges after VARIANTS and the counters after STATS_REPLY; version-1
 * encodings stay byte for byte what they were, and decode with none. */
static void test_version2(void **state) {
  (void)state;
  assert_int_equal(hfp_negotiate(1, 1), 1);
  assert_int_equal(hfp_negotiate(1, 2), 2);
  assert_int_equal(hfp_negotiate(2, 2), 2);
  assert_int_equal(hfp_negotiate(1, 9), HFP_VERSION);
  assert_int_equal(hfp_negotiate(HFP_VERSION + 1, HFP_VERSION + 2), -HFP_E_VERSION);
  assert_int_equal(hfp_negotiate(2, 1), -HFP_E_VERSION);

  hfp_hello_ok ok = {2, 0, 64, 64, 4, 8, 3, 2, 16, 1 << 20, "srv", "0.1.0"}, okd;
  int n = hfp_encode_hello_ok(buf, sizeof buf, &ok);
  hfp_header h;
  const uint8_t *p = split(buf, n, HFP_HELLO_OK, &h);
  assert_int_equal(hfp_decode_hello_ok(p, h.length, &okd), 0);
  assert_int_equal(okd.version, 2);
  assert_string_equal(okd.software_version, "0.1.0");
  ok.version = HFP_VERSION + 1;
  assert_int_equal(hfp_encode_hello_ok(buf, sizeof buf, &ok), -HFP_E_INVALID);

  /* RESULT: bit 3 says the input is out of range, bit 2 that it was
   * sanitised; bits 4..7 are no one's. */
  float data[2 * 1 * 3] = {0};
  hfp_result r = {0, HFP_F32, HFP_RESULT_OUT_OF_RANGE, 2, 1, 1, {1, 2, 3, 4, 10},
                  data, sizeof data, NULL, 0}, rd;
  uint64_t total;
  n = hfp_encode_result_head(buf, sizeof buf, 9, &r, &total);
  assert_true(n > 0);
  memcpy(buf + n, data, sizeof data);
  p = split(buf, (int)total, HFP_RESULT, &h);
  assert_int_equal(hfp_decode_result(p, h.length, &rd), 0);
  assert_int_equal(rd.flags, HFP_RESULT_OUT_OF_RANGE);
  r.flags = HFP_RESULT_INPUT_SANITISED | HFP_RESULT_OUT_OF_RANGE;
  n = hfp_encode_result_head(buf, sizeof buf, 9, &r, &total);
  assert_true(n > 0);
  memcpy(buf + n, data, sizeof data);
  p = split(buf, (int)total, HFP_RESULT, &h);
  assert_int_equal(hfp_decode_result(p, h.length, &rd), 0);
  assert_int_equal(rd.flags, HFP_RESULT_INPUT_SANITISED | HFP_RESULT_OUT_OF_RANGE);
  static uint8_t cr[256];
  memcpy(cr, p, h.length);
  cr[3] = 0x10;  /* an unknown bit */
  assert_int_equal(hfp_decode_result(cr, h.length, &rd), -HFP_E_INVALID);
  r.flags = 0x10;
  assert_int_equal(hfp_encode_result_head(buf, sizeof buf, 9, &r, &total), -HFP_E_INVALID);
  r.flags = HFP_RESULT_OUT_OF_RANGE;
  r.status = HFP_E_INTERNAL;   /* a failed request carries no flags */
  r.width = r.height = r.batch = 0;
  r.data = NULL;
  r.data_len = 0;
  assert_int_equal(hfp_encode_result_head(buf, sizeof buf, 9, &r, &total), -HFP_E_INVALID);
  r.flags = HFP_RESULT_INPUT_SANITISED;
  assert_int_equal(hfp_encode_result_head(buf, sizeof buf, 9, &r, &total), -HFP_E_INVALID);

  /* VARIANTS with ranges. */
  hfp_variant v[2], d[HFP_MAX_VARIANTS];
  two_variants(v);
  v[1].num_ranges = 2;
  v[1].ranges[0].stat = 0, v[1].ranges[0].lo = 0.015, v[1].ranges[0].hi = 0.0190001;
  v[1].ranges[1].stat = 4, v[1].ranges[1].lo = 256, v[1].ranges[1].hi = 1024;
  int n1 = hfp_encode_variants(buf, sizeof buf, v, 2);
  static uint8_t v1[1024];
  memcpy(v1, buf, (size_t)n1);
  int n2 = hfp_encode_variants_v(buf, sizeof buf, v, 2, 2);
  assert_int_equal((size_t)n2, hfp_frame_size_variants_v(v, 2, 2));
  /* 1 byte for V0's empty block, 1 + 2 x 17 for V1's */
  assert_int_equal(n2, n1 + 1 + 1 + 2 * 17);
  assert_memory_equal(buf + HFP_HEADER_SIZE, v1 + HFP_HEADER_SIZE, (size_t)n1 - HFP_HEADER_SIZE);
  p = split(buf, n2, HFP_VARIANTS, &h);
  int count = 0;
  assert_int_equal(hfp_decode_variants(p, h.length, d, HFP_MAX_VARIANTS, &count), 0);
  assert_int_equal(count, 2);
  assert_memory_equal(&d[0], &v[0], sizeof v[0]);
  assert_int_equal(d[1].num_ranges, 2);
  assert_true(d[1].ranges[0].stat == 0 && d[1].ranges[0].lo == 0.015 &&
              d[1].ranges[0].hi == 0.0190001);
  assert_true(d[1].ranges[1].stat == 4 && d[1].ranges[1].hi == 1024);
  for (uint32_t len = (uint32_t)n1 - HFP_HEADER_SIZE + 1; len < h.length; len++)
    assert_int_equal(hfp_decode_variants(p, len, d, HFP_MAX_VARIANTS, &count), -HFP_E_LENGTH);
  /* the version-1 frame decodes with no ranges */
  p = split(v1, n1, HFP_VARIANTS, &h);
  assert_int_equal(hfp_decode_variants(p, h.length, d, HFP_MAX_VARIANTS, &count), 0);
  assert_int_equal(d[1].num_ranges, 0);
  /* bad ranges are refused both ways */
  static uint8_t c[2048];
  n2 = hfp_encode_variants_v(buf, sizeof buf, v, 2, 2);
  size_t last = (size_t)n2 - 17;            /* V1's second triple */
  memcpy(c, buf, (size_t)n2);
  c[last] = 0;                              /* the same statistic twice */
  assert_int_equal(hfp_decode_variants(c + HFP_HEADER_SIZE, (size_t)n2 - HFP_HEADER_SIZE, d,
                                       HFP_MAX_VARIANTS, &count), -HFP_E_INVALID);
  memcpy(c, buf, (size_t)n2);
  memset(c + last + 1, 0xff, 8);            /* low is NaN */
  assert_int_equal(hfp_decode_variants(c + HFP_HEADER_SIZE, (size_t)n2 - HFP_HEADER_SIZE, d,
                                       HFP_MAX_VARIANTS, &count), -HFP_E_INVALID);
  memcpy(c, buf, (size_t)n2);
  c[n1 + 1] = HFP_MAX_STATS + 1;            /* V1's count */
  assert_int_equal(hfp_decode_variants(c + HFP_HEADER_SIZE, (size_t)n2 - HFP_HEADER_SIZE, d,
                                       HFP_MAX_VARIANTS, &count), -HFP_E_INVALID);
  v[1].ranges[1].lo = 2000;                 /* low > high */
  assert_int_equal(hfp_encode_variants_v(buf, sizeof buf, v, 2, 2), -HFP_E_INVALID);
  v[1].ranges[1].lo = 256;
  v[1].ranges[1].stat = 0;
  assert_int_equal(hfp_encode_variants_v(buf, sizeof buf, v, 2, 2), -HFP_E_INVALID);

  /* STATS_REPLY: the out-of-range and sanitised counters after the entries. */
  static hfp_stats m, sd;
  memset(&m, 0, sizeof m);
  m.num_variants = 2;
  strcpy(m.variants[0].name, "A");
  strcpy(m.variants[1].name, "B");
  m.variants[0].requests_ok = 5;
  m.variants[1].out_of_range = 7;
  m.variants[0].frames_sanitised = 3;
  m.variants[1].frames_sanitised = 1ull << 40;
  m.variants[0].cache_bytes = 123456789;
  n1 = hfp_encode_stats(buf, sizeof buf, &m);
  memcpy(v1, buf, (size_t)n1);
  n2 = hfp_encode_stats_v(buf, sizeof buf, &m, 2);
  assert_int_equal((size_t)n2, hfp_frame_size_stats_v(&m, 2));
  assert_int_equal(n2, n1 + 2 + 2 * 3 * 8);   /* versions 2 and 3: three counters */
  p = split(buf, n2, HFP_STATS_REPLY, &h);
  assert_int_equal(hfp_decode_stats(p, h.length, &sd), 0);
  assert_memory_equal(&sd, &m, sizeof m);
  for (uint32_t len = (uint32_t)n1 - HFP_HEADER_SIZE + 1; len < h.length; len++)
    assert_int_not_equal(hfp_decode_stats(p, len, &sd), 0);
  p = split(v1, n1, HFP_STATS_REPLY, &h);   /* version 1: counted, not sent */
  assert_int_equal(hfp_decode_stats(p, h.length, &sd), 0);
  assert_true(sd.variants[1].out_of_range == 0 && sd.variants[0].requests_ok == 5);
  assert_true(sd.variants[0].frames_sanitised == 0 && sd.variants[1].frames_sanitised == 0);
  assert_true(sd.variants[0].cache_bytes == 0 && sd.variants[1].cache_bytes == 0);
  /* A newer peer's six counters: the first five are ours, the rest skipped. */
  assert_true((size_t)n1 + 2 + 2 * 6 * 8 <= sizeof c);
  memcpy(c, v1, (size_t)n1);
  size_t off = (size_t)n1;
  hfp_put_u16(c + off, 6), off += 2;
  for (int i = 0; i < 2; i++)
    for (int k = 0; k < 6; k++, off += 8) {
      hfp_put_u32(c + off, (uint32_t)(10 * i + k + 1));
      hfp_put_u32(c + off + 4, 0);
    }
  assert_int_equal(hfp_decode_stats(c + HFP_HEADER_SIZE, off - HFP_HEADER_SIZE, &sd), 0);
  assert_true(sd.variants[0].out_of_range == 1 && sd.variants[1].out_of_range == 11);
  assert_true(sd.variants[0].frames_sanitised == 2 && sd.variants[1].frames_sanitised == 12);
  assert_true(sd.variants[0].cache_bytes == 3 && sd.variants[1].cache_bytes == 13);
  assert_true(sd.variants[0].expired == 4 && sd.variants[1].expired == 14);
  assert_true(sd.variants[0].cancelled == 5 && sd.variants[1].cancelled == 15);
  hfp_put_u16(c + n1, 0);                   /* no counters: not a valid block */
  assert_int_equal(hfp_decode_stats(c + HFP_HEADER_SIZE, (size_t)n1 + 2 - HFP_HEADER_SIZE, &sd),
                   -HFP_E_INVALID);
}

/* Version 3 (PROTOCOL.md, "Version 3"): the estimate each variant reads
 * after VARIANTS' ranges, and FILTER flag ESTIMATE, whose tensor is the
 * features followed by W*H*3 values; version-2 encodings stay what they
 * were and decode with no estimate. */
static void test_version3(void **state) {
  (void)state;
  assert_int_equal(hfp_negotiate(1, 3), 3);
  assert_int_equal(hfp_negotiate(3, 3), 3);
  assert_int_equal(hfp_negotiate(1, 2), 2);

  hfp_variant v[2], d[HFP_MAX_VARIANTS];
  two_variants(v);
  v[1].estimate = HFP_ESTIMATE_ALPHA_CORRECTED;
  int n2 = hfp_encode_variants_v(buf, sizeof buf, v, 2, 2);
  static uint8_t v2[1024];
  memcpy(v2, buf, (size_t)n2);
  int n3 = hfp_encode_variants_v(buf, sizeof buf, v, 2, 3);
  assert_int_equal((size_t)n3, hfp_frame_size_variants_v(v, 2, 3));
  assert_int_equal(n3, n2 + 2);   /* a byte per entry */
  assert_memory_equal(buf + HFP_HEADER_SIZE, v2 + HFP_HEADER_SIZE, (size_t)n2 - HFP_HEADER_SIZE);
  hfp_header h;
  const uint8_t *p = split(buf, n3, HFP_VARIANTS, &h);
  int count = 0;
  assert_int_equal(hfp_decode_variants(p, h.length, d, HFP_MAX_VARIANTS, &count), 0);
  assert_int_equal(count, 2);
  assert_int_equal(d[0].estimate, HFP_ESTIMATE_NONE);
  assert_int_equal(d[1].estimate, HFP_ESTIMATE_ALPHA_CORRECTED);
  /* cut inside the estimate block, or an estimate no one knows */
  assert_int_equal(hfp_decode_variants(p, h.length - 1, d, HFP_MAX_VARIANTS, &count),
                   -HFP_E_LENGTH);
  static uint8_t c[1024];
  memcpy(c, p, h.length);
  c[h.length - 1] = 2;
  assert_int_equal(hfp_decode_variants(c, h.length, d, HFP_MAX_VARIANTS, &count), -HFP_E_INVALID);
  v[1].estimate = 2;
  assert_int_equal(hfp_encode_variants_v(buf, sizeof buf, v, 2, 3), -HFP_E_INVALID);
  /* the version-2 frame: no estimate, the field not sent */
  p = split(v2, n2, HFP_VARIANTS, &h);
  assert_int_equal(hfp_decode_variants(p, h.length, d, HFP_MAX_VARIANTS, &count), 0);
  assert_int_equal(d[1].estimate, HFP_ESTIMATE_NONE);
  assert_int_equal(hfp_encode_variants_v(buf, sizeof buf, v, 2, 2), n2);

  /* FILTER with ESTIMATE: 3 x 2 pixels of 4 spp and 3 estimate values. */
  uint64_t bytes;
  assert_int_equal(hfp_filter_input_bytes(3, 2, 4, HFP_F32, HFP_FILTER_ESTIMATE, &bytes), 0);
  assert_int_equal(bytes, 3 * 2 * 27 * 4);
  assert_int_equal(hfp_filter_input_bytes(3, 2, 4, HFP_F16, 0, &bytes), 0);
  assert_int_equal(bytes, 3 * 2 * 24 * 2);
  static float t[3 * 2 * 27];
  hfp_filter f = {"V1", HFP_FILTER_ESTIMATE, 3, 2, 4, HFP_F32, HFP_F32, {0}, {0}, {0}, t,
                  sizeof t, 0, 0, 0, 0, 0}, fd;
  uint64_t total;
  int n = hfp_encode_filter_head(buf, sizeof buf, 5, &f, &total);
  assert_true(n > 0);
  memcpy(buf + n, t, sizeof t);
  p = split(buf, (int)total, HFP_FILTER, &h);
  assert_int_equal(hfp_decode_filter(p, h.length, &fd), 0);
  assert_int_equal(fd.flags, HFP_FILTER_ESTIMATE);
  assert_int_equal(fd.data_len, sizeof t);
  /* the features alone with the flag: the length disagrees */
  f.data_len = 3 * 2 * 24 * 4;
  assert_int_equal(hfp_encode_filter_head(buf, sizeof buf, 5, &f, &total), -HFP_E_INVALID);
  memcpy(c, p, h.length);
  assert_int_equal(hfp_decode_filter(c, h.length - 3 * 2 * 3 * 4, &fd), -HFP_E_LENGTH);
  /* by reference: the input region holds both */
  f.flags = HFP_FILTER_ESTIMATE | HFP_FILTER_SHM;
  f.shm_segment = 1, f.shm_in = 0, f.shm_out = sizeof t;
  assert_int_equal(hfp_shm_check(&f, sizeof t + 3 * 2 * 3 * 4), 0);
  f.shm_out = sizeof t - 4;  /* overlaps the estimate */
  assert_int_equal(hfp_shm_check(&f, sizeof t + 3 * 2 * 3 * 4), -HFP_E_LENGTH);
  f.shm_out = sizeof t;
  assert_int_equal(hfp_shm_check(&f, sizeof t + 3 * 2 * 3 * 4 - 4), -HFP_E_LENGTH);
}

/* Version 4 (PROTOCOL.md, "Version 4"): FILTER flag DEADLINE and its
 * budget after the variant name, before the tensor or the SHM reference;
 * the status EXPIRED; a fourth and a fifth counter after STATS_REPLY's
 * entries (expired, cancelled). */
static void test_version4(void **state) {
  (void)state;
  assert_int_equal(HFP_VERSION, 4);
  assert_int_equal(hfp_negotiate(1, 4), 4);
  assert_int_equal(hfp_negotiate(1, 3), 3);
  assert_string_equal(hfp_code_name(HFP_E_EXPIRED), "EXPIRED");
  assert_string_equal(hfp_code_name(HFP_E_CANCELLED), "CANCELLED");
  /* CANCEL: the FILTER's id, an empty payload; never id 0 */
  {
    uint8_t cb[HFP_HEADER_SIZE];
    assert_int_equal(hfp_encode_empty(cb, sizeof cb, HFP_CANCEL, 0), -HFP_E_INVALID);
    assert_int_equal(hfp_encode_empty(cb, sizeof cb, HFP_CANCEL, 7), HFP_HEADER_SIZE);
    hfp_header ch;
    assert_int_equal(hfp_header_decode(cb, 0, &ch), 0);
    assert_int_equal(ch.type, HFP_CANCEL);
    assert_int_equal(ch.request_id, 7);
    assert_int_equal(ch.length, 0);
    assert_int_equal(hfp_encode_empty(cb, sizeof cb, HFP_STATS, 0), HFP_HEADER_SIZE);
  }
  assert_non_null(strstr(hfp_strerror(-HFP_E_EXPIRED), "deadline"));

  static float t[3 * 2 * 24];
  hfp_filter f = {"V1", HFP_FILTER_DEADLINE, 3, 2, 4, HFP_F32, HFP_F32, {0}, {0}, {0}, t,
                  sizeof t, 0, 0, 0, 0, 16000}, fd;
  uint64_t total;
  int n = hfp_encode_filter_head(buf, sizeof buf, 5, &f, &total);
  assert_int_equal(n, HFP_HEADER_SIZE + HFP_FILTER_FIXED + 2 + HFP_DEADLINE_SIZE);
  assert_int_equal(total, (uint64_t)n + sizeof t);
  /* the budget right after the name, little-endian */
  assert_int_equal(hfp_get_u32(buf + HFP_HEADER_SIZE + HFP_FILTER_FIXED + 2), 16000);
  memcpy(buf + n, t, sizeof t);
  hfp_header h;
  const uint8_t *p = split(buf, (int)total, HFP_FILTER, &h);
  assert_int_equal(hfp_decode_filter(p, h.length, &fd), 0);
  assert_int_equal(fd.flags, HFP_FILTER_DEADLINE);
  assert_int_equal(fd.budget_us, 16000);
  assert_ptr_equal(fd.data, p + HFP_FILTER_FIXED + 2 + HFP_DEADLINE_SIZE);
  /* the head alone, as a server reads it: not whole until the budget is in */
  size_t head = 0;
  assert_int_equal(hfp_decode_filter_head(p, HFP_FILTER_FIXED + 2 + 3, h.length, &fd, &head),
                   -HFP_E_NOSPACE);
  assert_int_equal(hfp_decode_filter_head(p, HFP_FILTER_FIXED + 2 + 4, h.length, &fd, &head), 0);
  assert_int_equal(head, HFP_FILTER_FIXED + 2 + HFP_DEADLINE_SIZE);
  /* the tensor without the budget the flag announces: the length disagrees */
  static uint8_t c[4096];
  memcpy(c, p, h.length);
  assert_int_equal(hfp_decode_filter(c, h.length - HFP_DEADLINE_SIZE, &fd), -HFP_E_LENGTH);
  /* a budget of 0 would expire the frame unseen: out of its domain */
  hfp_put_u32(c + HFP_FILTER_FIXED + 2, 0);
  assert_int_equal(hfp_decode_filter(c, h.length, &fd), -HFP_E_INVALID);
  assert_string_equal(fd.variant, "V1");   /* charged to the variant it names */
  f.budget_us = 0;
  assert_int_equal(hfp_encode_filter_head(buf, sizeof buf, 5, &f, &total), -HFP_E_INVALID);
  /* a budget without the flag would be lost on the wire */
  f.flags = 0, f.budget_us = 100;
  assert_int_equal(hfp_encode_filter_head(buf, sizeof buf, 5, &f, &total), -HFP_E_INVALID);
  /* the largest budget */
  f.flags = HFP_FILTER_DEADLINE, f.budget_us = UINT32_MAX;
  n = hfp_encode_filter_head(buf, sizeof buf, 5, &f, &total);
  assert_true(n > 0);
  memcpy(buf + n, t, sizeof t);
  p = split(buf, (int)total, HFP_FILTER, &h);
  assert_int_equal(hfp_decode_filter(p, h.length, &fd), 0);
  assert_int_equal(fd.budget_us, UINT32_MAX);

  /* by reference: the budget, then the reference */
  f.flags = HFP_FILTER_DEADLINE | HFP_FILTER_SHM, f.budget_us = 7;
  f.shm_segment = 3, f.shm_in = 0, f.shm_out = sizeof t, f.data = NULL;
  n = hfp_encode_filter_head(buf, sizeof buf, 5, &f, &total);
  assert_int_equal(n, HFP_HEADER_SIZE + HFP_FILTER_FIXED + 2 + HFP_DEADLINE_SIZE +
                          HFP_SHM_REF_SIZE);
  assert_true(n <= HFP_FILTER_HEAD_MAX);
  p = split(buf, n, HFP_FILTER, &h);
  assert_int_equal(hfp_decode_filter(p, h.length, &fd), 0);
  assert_int_equal(fd.budget_us, 7);
  assert_int_equal(fd.shm_segment, 3);
  assert_int_equal(fd.shm_out, sizeof t);

  /* RESULT with status EXPIRED: the fixed fields alone */
  hfp_result r = {0};
  r.status = HFP_E_EXPIRED;
  r.timing.queue_us = r.timing.total_us = 17000;
  n = hfp_encode_result_head(buf, sizeof buf, 5, &r, &total);
  assert_int_equal(n, HFP_HEADER_SIZE + HFP_RESULT_FIXED);
  hfp_result rd;
  p = split(buf, n, HFP_RESULT, &h);
  assert_int_equal(hfp_decode_result(p, h.length, &rd), 0);
  assert_int_equal(rd.status, HFP_E_EXPIRED);
  assert_true(rd.timing.queue_us == 17000);
  /* and as an ERROR code */
  hfp_error e = {HFP_E_EXPIRED, 0, "late"}, ed;
  n = hfp_encode_error(buf, sizeof buf, 5, &e);
  p = split(buf, n, HFP_ERROR, &h);
  assert_int_equal(hfp_decode_error(p, h.length, &ed), 0);
  assert_int_equal(ed.code, HFP_E_EXPIRED);

  /* STATS_REPLY: five counters from version 4, the fourth expired, the
   * fifth cancelled */
  static hfp_stats m, sd;
  memset(&m, 0, sizeof m);
  m.num_variants = 2;
  strcpy(m.variants[0].name, "A");
  strcpy(m.variants[1].name, "B");
  m.variants[0].expired = 9;
  m.variants[1].expired = 1ull << 33;
  m.variants[1].cache_bytes = 5;
  m.variants[0].cancelled = 3;
  m.variants[1].cancelled = 1ull << 34;
  int n3 = hfp_encode_stats_v(buf, sizeof buf, &m, 3);
  int n4 = hfp_encode_stats_v(c, sizeof c, &m, 4);
  assert_int_equal((size_t)n4, hfp_frame_size_stats_v(&m, 4));
  assert_int_equal(n4, n3 + 2 * 2 * 8);
  p = split(c, n4, HFP_STATS_REPLY, &h);
  assert_int_equal(hfp_decode_stats(p, h.length, &sd), 0);
  assert_memory_equal(&sd, &m, sizeof m);
  p = split(buf, n3, HFP_STATS_REPLY, &h);   /* version 3: counted, not sent */
  assert_int_equal(hfp_decode_stats(p, h.length, &sd), 0);
  assert_true(sd.variants[0].expired == 0 && sd.variants[1].expired == 0);
  assert_true(sd.variants[0].cancelled == 0 && sd.variants[1].cancelled == 0);
  assert_true(sd.variants[1].cache_bytes == 5);
  /* A version-4 peer that sends four counters (before cancelled was
   * appended): expired read, cancelled 0. */
  uint8_t *tail = c + n4 - 2 * 5 * 8 - 2;
  assert_int_equal(hfp_get_u16(tail), 5);
  hfp_put_u16(tail, 4);
  const uint64_t four[2][4] = {{0, 0, 0, 9}, {0, 0, 5, 1ull << 33}};
  for (int i = 0; i < 2; i++)
    for (int k = 0; k < 4; k++) {
      uint8_t *at = tail + 2 + (size_t)(i * 4 + k) * 8;
      hfp_put_u32(at, (uint32_t)four[i][k]);
      hfp_put_u32(at + 4, (uint32_t)(four[i][k] >> 32));
    }
  size_t end = (size_t)(tail - c) + 2 + 2 * 4 * 8;
  assert_int_equal(hfp_decode_stats(c + HFP_HEADER_SIZE, end - HFP_HEADER_SIZE, &sd), 0);
  assert_true(sd.variants[0].expired == 9 && sd.variants[1].expired == 1ull << 33);
  assert_true(sd.variants[1].cache_bytes == 5);
  assert_true(sd.variants[0].cancelled == 0 && sd.variants[1].cancelled == 0);
}

static void test_filter_shm(void **state) {
  (void)state;
  hfp_filter m = sample_filter(NULL, 8, 4, 2), d;
  m.flags = HFP_FILTER_SHM | HFP_FILTER_COMPOSITE;
  m.shm_segment = 3;
  m.shm_in = 0;
  m.shm_out = 4096;
  m.shm_rgba = 8192;
  uint64_t total;
  int n = hfp_encode_filter_head(buf, sizeof buf, 7, &m, &total);
  assert_int_equal(n, HFP_HEADER_SIZE + HFP_FILTER_FIXED + 4 + HFP_SHM_REF_SIZE);
  assert_int_equal(total, (uint64_t)n); /* no tensor follows */
  hfp_header h;
  const uint8_t *p = split(buf, n, HFP_FILTER, &h);
  assert_int_equal(hfp_decode_filter(p, h.length, &d), 0);
  assert_int_equal(d.shm_segment, 3);
  assert_int_equal(d.shm_in, 0);
  assert_int_equal(d.shm_out, 4096);
  assert_int_equal(d.shm_rgba, 8192);
  assert_null(d.data);
  assert_int_equal(d.data_len, 8 * 4 * 2 * 6 * 4);
  /* head decoding wants the reference too */
  size_t head;
  assert_int_equal(hfp_decode_filter_head(p, HFP_FILTER_FIXED + 4, h.length, &d, &head),
                   -HFP_E_NOSPACE);
  /* a reference cut short is found before the name is read: no name */
  for (uint32_t len = 0; len < h.length; len++) {
    assert_int_equal(hfp_decode_filter(p, len, &d), -HFP_E_LENGTH);
    assert_string_equal(d.variant, "");
  }
  uint8_t c[256];
  memcpy(c, p, h.length);
  assert_int_equal(hfp_decode_filter(c, h.length + 1, &d), -HFP_E_LENGTH);
  assert_string_equal(d.variant, "Base");
  /* faults in the reference's fields come after the name: it is kept */
  size_t ref = HFP_FILTER_FIXED + 4;
  memcpy(c, p, h.length);
  hfp_put_u32(c + ref, 0); /* segment 0 */
  assert_int_equal(hfp_decode_filter(c, h.length, &d), -HFP_E_INVALID);
  assert_string_equal(d.variant, "Base");
  memcpy(c, p, h.length);
  hfp_put_u32(c + ref + 4, 1); /* reserved */
  assert_int_equal(hfp_decode_filter(c, h.length, &d), -HFP_E_INVALID);
  assert_string_equal(d.variant, "Base");
  memcpy(c, p, h.length);
  hfp_put_u16(c + 2, HFP_FILTER_SHM); /* rgba offset without COMPOSITE */
  assert_int_equal(hfp_decode_filter(c, h.length, &d), -HFP_E_INVALID);
  assert_string_equal(d.variant, "Base");
  m.shm_segment = 0;
  assert_int_equal(hfp_encode_filter_head(buf, sizeof buf, 7, &m, &total), -HFP_E_INVALID);

  /* bounds and alignment against the segment */
  m.shm_segment = 3;
  assert_int_equal(hfp_decode_filter(p, h.length, &d), 0);
  uint64_t rgba_end = 8192 + 8 * 4 * 4 * 2;
  assert_int_equal(hfp_shm_check(&d, rgba_end), 0);
  assert_int_equal(hfp_shm_check(&d, rgba_end - 1), -HFP_E_LENGTH);
  d.shm_out = 4097; /* f16 output at an odd byte */
  assert_int_equal(hfp_shm_check(&d, 1 << 20), -HFP_E_LENGTH);
  d.shm_out = 4096;
  d.shm_in = UINT64_MAX - 3; /* offset + length overflows */
  assert_int_equal(hfp_shm_check(&d, UINT64_MAX), -HFP_E_LENGTH);
  d.shm_in = 2; /* f32 input not 4-aligned */
  assert_int_equal(hfp_shm_check(&d, 1 << 20), -HFP_E_LENGTH);
  /* what a client is told: which region, and how it is wrong */
  char why[200];
  assert_int_equal(hfp_shm_check_why(&d, 1 << 20, why, sizeof why), -HFP_E_LENGTH);
  assert_string_equal(why, "the features: offset 2 is not a multiple of the 4-byte elements");
  d.shm_in = 0;
  d.shm_out = 4096;
  assert_int_equal(hfp_shm_check_why(&d, 4100, why, sizeof why), -HFP_E_LENGTH);
  assert_non_null(strstr(why, "the result: "));
  assert_non_null(strstr(why, " bytes at offset 4096 would end past the segment's 4100 bytes"));
  assert_int_equal(hfp_shm_check_why(&d, 4100, NULL, 0), -HFP_E_LENGTH);   /* why optional */
  d.shm_in = 2;

  /* regions may touch but not share a byte */
  uint64_t in_len = 0, out_len = 0;
  assert_int_equal(hfp_features_bytes(d.width, d.height, d.spp, d.in_dtype, &in_len), 0);
  assert_int_equal(hfp_output_bytes(d.width, d.height, HFP_OUTPUTS, d.out_dtype, &out_len), 0);
  d.shm_in = 0;
  d.shm_out = in_len; /* right after the features */
  d.shm_rgba = in_len + out_len;
  assert_int_equal(hfp_shm_check(&d, 1 << 20), 0);
  d.shm_out = in_len - 2; /* its first element on the features' last */
  assert_int_equal(hfp_shm_check(&d, 1 << 20), -HFP_E_LENGTH);
  d.shm_out = 0; /* in place */
  assert_int_equal(hfp_shm_check(&d, 1 << 20), -HFP_E_LENGTH);
  d.shm_out = in_len;
  d.shm_rgba = in_len + out_len - 2; /* the composite on the result's last element */
  assert_int_equal(hfp_shm_check(&d, 1 << 20), -HFP_E_LENGTH);
  d.shm_rgba = 0; /* the composite on the features */
  assert_int_equal(hfp_shm_check(&d, 1 << 20), -HFP_E_LENGTH);
  assert_int_equal(hfp_shm_check_why(&d, 1 << 20, why, sizeof why), -HFP_E_LENGTH);
  assert_string_equal(why, "the features and the rgba composite overlap");
  d.flags &= (uint16_t)~HFP_FILTER_COMPOSITE; /* no composite: its offset is not a region */
  assert_int_equal(hfp_shm_check(&d, 1 << 20), 0);

  /* a RESULT for it carries no tensor */
  hfp_result r;
  memset(&r, 0, sizeof r);
  r.dtype = HFP_F16;
  r.flags = HFP_FILTER_SHM | HFP_FILTER_COMPOSITE;
  r.width = 8;
  r.height = 4;
  r.batch = 1;
  n = hfp_encode_result_head(buf, sizeof buf, 7, &r, &total);
  assert_int_equal(total, (uint64_t)n);
  p = split(buf, n, HFP_RESULT, &h);
  hfp_result rd;
  assert_int_equal(hfp_decode_result(p, h.length, &rd), 0);
  assert_int_equal(rd.flags, HFP_FILTER_SHM | HFP_FILTER_COMPOSITE);
  assert_null(rd.data);
  assert_null(rd.rgba);
  r.data_len = 10;
  assert_int_equal(hfp_encode_result_head(buf, sizeof buf, 7, &r, &total), -HFP_E_INVALID);
}

static void test_regions_overlap(void **state) {
  (void)state;
  assert_true(hfp_regions_overlap(0, 10, 9, 1));    /* one byte shared */
  assert_false(hfp_regions_overlap(0, 10, 10, 5));  /* touching */
  assert_false(hfp_regions_overlap(10, 5, 0, 10));
  assert_true(hfp_regions_overlap(4, 2, 0, 10));    /* one inside the other */
  assert_true(hfp_regions_overlap(0, 10, 4, 2));
  assert_false(hfp_regions_overlap(0, 10, 5, 0));   /* empty ranges share nothing */
  assert_false(hfp_regions_overlap(5, 0, 0, 10));
  assert_true(hfp_regions_overlap(UINT64_MAX - 8, 8, UINT64_MAX - 1, 1));
}

static void test_shm_messages(void **state) {
  (void)state;
  hfp_header h;
  uint64_t bytes;
  uint32_t seg;
  int n = hfp_encode_shm_create(buf, sizeof buf, 123456789012ull);
  const uint8_t *p = split(buf, n, HFP_SHM_CREATE, &h);
  assert_int_equal(hfp_decode_shm_create(p, h.length, &bytes), 0);
  assert_int_equal(bytes, 123456789012ull);
  assert_int_equal(hfp_decode_shm_create(p, h.length - 1, &bytes), -HFP_E_LENGTH);
  uint8_t zero[12] = {0};
  assert_int_equal(hfp_decode_shm_create(zero, 8, &bytes), -HFP_E_INVALID);
  assert_int_equal(hfp_encode_shm_create(buf, sizeof buf, 0), -HFP_E_INVALID);

  n = hfp_encode_shm_created(buf, sizeof buf, 9, 4096);
  p = split(buf, n, HFP_SHM_CREATED, &h);
  assert_int_equal(hfp_decode_shm_created(p, h.length, &seg, &bytes), 0);
  assert_int_equal(seg, 9);
  assert_int_equal(bytes, 4096);
  assert_int_equal(hfp_decode_shm_created(p, h.length + 1, &seg, &bytes), -HFP_E_LENGTH);
  assert_int_equal(hfp_decode_shm_created(zero, 12, &seg, &bytes), -HFP_E_INVALID);
  assert_int_equal(hfp_encode_shm_created(buf, sizeof buf, 0, 1), -HFP_E_INVALID);

  n = hfp_encode_shm_destroy(buf, sizeof buf, 9);
  p = split(buf, n, HFP_SHM_DESTROY, &h);
  assert_int_equal(hfp_decode_shm_destroy(p, h.length, &seg), 0);
  assert_int_equal(seg, 9);
  assert_int_equal(hfp_decode_shm_destroy(p, 3, &seg), -HFP_E_LENGTH);
  assert_int_equal(hfp_decode_shm_destroy(zero, 4, &seg), -HFP_E_INVALID);
  assert_int_equal(hfp_encode_shm_destroy(buf, sizeof buf, 0), -HFP_E_INVALID);
}

static void test_histogram(void **state) {
  (void)state;
  assert_int_equal(hfp_hist_bucket(0), 0);
  assert_int_equal(hfp_hist_bucket(31), 0);
  assert_int_equal(hfp_hist_bucket(32), 1);
  assert_int_equal(hfp_hist_bucket(63), 1);
  assert_int_equal(hfp_hist_bucket(64), 2);
  assert_int_equal(hfp_hist_bucket(UINT64_MAX), HFP_HIST_BUCKETS - 1);
  for (int i = 0; i < HFP_HIST_BUCKETS - 1; i++) {
    uint64_t up = hfp_hist_upper(i);
    assert_int_equal(hfp_hist_bucket(up - 1), i);
    assert_int_equal(hfp_hist_bucket(up), i + 1);
  }
  assert_true(hfp_hist_upper(HFP_HIST_BUCKETS - 1) == UINT64_MAX);
}

/* The largest FILTER head there is (a 64-byte name, DEADLINE and SHM)
 * encodes into HFP_FILTER_HEAD_MAX bytes, the buffer libhairfilter gives
 * it: a frame by reference to a variant of a long name was refused
 * locally (HFC_E_ARG) when the macro left the reference out. */
static void test_head_max(void **state) {
  (void)state;
  hfp_filter f;
  memset(&f, 0, sizeof f);
  memset(f.variant, 'v', HFP_NAME_MAX);
  f.variant[HFP_NAME_MAX] = 0;
  f.flags = HFP_FILTER_DEADLINE | HFP_FILTER_SHM | HFP_FILTER_COMPOSITE;
  f.budget_us = 1;
  f.width = f.height = 1;
  f.spp = 1;
  f.in_dtype = f.out_dtype = HFP_F32;
  assert_int_equal(hfp_features_bytes(1, 1, 1, HFP_F32, &f.data_len), 0);
  f.shm_segment = 1, f.shm_in = 0, f.shm_out = 4096, f.shm_rgba = 8192;
  uint8_t head[HFP_FILTER_HEAD_MAX];
  uint64_t total;
  int n = hfp_encode_filter_head(head, sizeof head, 9, &f, &total);
  assert_int_equal(n, HFP_HEADER_SIZE + HFP_FILTER_FIXED + HFP_NAME_MAX + HFP_DEADLINE_SIZE +
                          HFP_SHM_REF_SIZE);
  assert_int_equal(n, HFP_FILTER_HEAD_MAX);
}

int main(void) {
  const struct CMUnitTest tests[] = {
    cmocka_unit_test(test_header),  cmocka_unit_test(test_hello),
    cmocka_unit_test(test_hello_fault), cmocka_unit_test(test_url),
    cmocka_unit_test(test_hello_ok), cmocka_unit_test(test_hello_ok_software),
    cmocka_unit_test(test_empty),
    cmocka_unit_test(test_variants), cmocka_unit_test(test_filter),
    cmocka_unit_test(test_result),  cmocka_unit_test(test_error),
    cmocka_unit_test(test_stats),   cmocka_unit_test(test_histogram),
    cmocka_unit_test(test_filter_shm), cmocka_unit_test(test_regions_overlap),
    cmocka_unit_test(test_shm_messages),
    cmocka_unit_test(test_version2),
    cmocka_unit_test(test_version3),
    cmocka_unit_test(test_version4),
    cmocka_unit_test(test_head_max),
  };
  return cmocka_run_group_tests(tests, NULL, NULL);
}
