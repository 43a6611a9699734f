/* The daemon's limits agree with one another and with what it announces
 * (PROTOCOL.md, "Handshake", "Flow control"; docs/SERVER.md, "Memory"):
 * a frame at exactly the announced maximum is served and one pixel more is
 * TOO_LARGE; a shared segment larger than the whole budget is TOO_LARGE,
 * one that does not fit now is BUSY; memory is charged as a frame arrives,
 * so frames only announced cannot crowd out a small one; and inference
 * memory is inside --max-memory-mb and given back after an oversized frame
 * (the daemon's peak and resident memory, from /proc), and so is all its
 * working memory under a mixed load of every variant and many sizes. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <poll.h>
#include <pthread.h>
#include <stdatomic.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <sys/stat.h>
#include <unistd.h>

#include "harness.h"
#include "harness_cmocka.h"
#include "proc_memory.h"

static harness H;

static int setup(void **state) {
  (void)state;
  return harness_init(&H);
}

static int teardown(void **state) {
  (void)state;
  harness_free(&H);
  return 0;
}

/* Reads the next reply on fd, which must be about id and not fatal:
 * returns its type, with an ERROR's code or a RESULT's status in *status
 * and the decoded RESULT in *r, whose tensors point into *payload (the
 * caller frees it). */
static int read_any_reply(int fd, uint32_t id, int *status, hfp_result *r, uint8_t **payload) {
  hfp_header h;
  assert_int_equal(raw_read(fd, &h, payload), 0);
  assert_int_equal(h.request_id, id);
  if (h.type == HFP_ERROR) {
    hfp_error e;
    assert_int_equal(hfp_decode_error(*payload, h.length, &e), 0);
    *status = (int)e.code;
    assert_int_equal(e.fatal, 0);
  } else {
    assert_int_equal(h.type, HFP_RESULT);
    assert_int_equal(hfp_decode_result(*payload, h.length, r), 0);
    *status = r->status;
  }
  return h.type;
}

/* read_any_reply where a RESULT must have status 0: *code is an ERROR's
 * code, else 0. */
static int read_reply(int fd, uint32_t id, int *code, hfp_result *r, uint8_t **payload) {
  int type = read_any_reply(fd, id, code, r, payload);
  if (type == HFP_RESULT) assert_int_equal(*code, 0);
  return type;
}

/* Sends one FILTER of variant at w x h (with a composite when rgba) on fd
 * and returns the reply's type; *code gets an ERROR's code, and the RESULT
 * is compared with the in-process reference. */
static int filter_once(int fd, uint32_t id, const char *variant, int w, int h, int rgba,
                       int *code) {
  const ref_variant *v = harness_variant(&H, variant);
  int spp = v->cfg.spp;
  float *in = make_features(w, h, spp, id);
  size_t len;
  uint8_t *f = raw_filter(id, variant, w, h, spp, in, &len);
  assert_non_null(f);
  if (rgba) hfp_put_u16(f + HFP_HEADER_SIZE + 2, HFP_FILTER_COMPOSITE);
  assert_int_equal(raw_send(fd, f, len), 0);
  hfp_result r;
  uint8_t *p;
  int type = read_reply(fd, id, code, &r, &p);
  if (type == HFP_RESULT) {
    size_t n = (size_t)w * h * 3;
    float *want = malloc(n * sizeof *want);
    assert_int_equal(reference(v, w, h, in, HF_F32, want, HF_F32), 0);
    assert_memory_equal(r.data, want, n * sizeof *want);
    free(want);
  }
  free(p);
  free(f);
  free(in);
  return type;
}

/* Sends n Small frames of w x h at once on c and waits for them all:
 * counts those served and those refused BUSY (anything else fails), and
 * the largest batch a served one ran in. */
typedef struct burst {
  int served, busy, max_batch;
} burst;

static burst send_burst(hfc_client *c, int w, int h, int n) {
  burst b = {0, 0, 0};
  float *in = make_features(w, h, 4, 12);
  float **out = calloc((size_t)n, sizeof *out);
  assert_non_null(in);
  assert_non_null(out);
  for (int i = 0; i < n; i++) {
    out[i] = malloc((size_t)w * h * 3 * sizeof(float));
    hfc_request r = TEST_REQUEST(.variant = "Small", .width = w, .height = h, .spp = 4, .in_dtype = HFC_F32,
                     .features = in, .out_dtype = HFC_F32, .result = out[i]);
    assert_int_equal(hfc_submit(c, &r, NULL), 0);
  }
  for (int k = 0; k < n; k++) {
    hfc_completion done;
    assert_int_equal(hfc_wait(c, 60000, &done), 0);
    if (done.status == 0) {
      b.served++;
      if (done.timing.batch > b.max_batch) b.max_batch = done.timing.batch;
    } else if (done.status == HFC_E_BUSY) {
      b.busy++;
    } else {
      fail_msg("frame %d: %s (%s)", k, hfc_strerror(done.status), hfc_last_message(c));
    }
  }
  for (int i = 0; i < n; i++) free(out[i]);
  free(out);
  free(in);
  return b;
}

/* A client that keeps its window of 4 full, resending the moment a reply
 * (a RESULT or a BUSY) comes back, until *stop. */
typedef struct hog {
  const server *d;
  atomic_int *stop;
  int served, busy, failed;
} hog;

static void *hog_main(void *arg) {
  hog *g = arg;
  enum { W = 96, WINDOW = 4 };
  hfc_client *c = client_connect(g->d, "hog");
  float *in = make_features(W, W, 4, 5);
  float *out = malloc((size_t)WINDOW * W * W * 3 * sizeof *out);
  if (!c || !in || !out) {
    g->failed = 1;
  } else {
    int pending = 0, slot_free[WINDOW] = {1, 1, 1, 1};
    while (!atomic_load(g->stop) || pending) {
      for (int k = 0; k < WINDOW && !atomic_load(g->stop); k++) {
        if (!slot_free[k]) continue;
        hfc_request r = TEST_REQUEST(.variant = "Small", .width = W, .height = W, .spp = 4,
                                     .in_dtype = HFC_F32, .features = in, .out_dtype = HFC_F32,
                                     .result = out + (size_t)k * W * W * 3,
                                     .user = (void *)(intptr_t)k);
        if (hfc_submit(c, &r, NULL)) {
          g->failed = 1;
          atomic_store(g->stop, 1);
          break;
        }
        slot_free[k] = 0;
        pending++;
      }
      if (!pending) break;
      hfc_completion done;
      if (hfc_wait(c, 60000, &done)) {
        g->failed = 1;
        break;
      }
      slot_free[(intptr_t)done.user] = 1;
      pending--;
      if (done.status == 0) g->served++;
      else if (done.status == HFC_E_BUSY) g->busy++;
      else g->failed = 1;
    }
  }
  if (c) hfc_close(c);
  free(out);
  free(in);
  return NULL;
}

/* Item: the queue's share refuses nothing within it (docs/SERVER.md,
 * "Limits and backpressure"): a connection alone fills a queue of 4 with a
 * window of 4, and two connections at the announced window of 4 fill a
 * queue of 8 together, with no BUSY. */
static void test_queue_share_within_window(void **state) {
  (void)state;
  enum { W = 64, WINDOW = 4, ROUNDS = 5 };
  float *in = make_features(W, W, 4, 21);
  float *out = malloc((size_t)2 * WINDOW * W * W * 3 * sizeof *out);
  assert_non_null(in);
  assert_non_null(out);
  for (int clients = 1; clients <= 2; clients++) {
    const char *queue = clients == 1 ? "4" : "8";
    const char *extra[] = {"--queue-size", queue, "--max-inflight", "4", "--max-batch", "1",
                           NULL};
    server d;
    if (server_start(&H, &d, extra)) fail_msg("daemon did not start");
    hfc_client *c[2] = {NULL, NULL};
    for (int k = 0; k < clients; k++) {
      c[k] = client_connect(&d, "window");
      assert_non_null(c[k]);
      assert_int_equal((int)hfc_info(c[k])->max_inflight, WINDOW);
    }
    for (int round = 0; round < ROUNDS; round++) {
      for (int i = 0; i < WINDOW; i++)
        for (int k = 0; k < clients; k++) {
          hfc_request r = TEST_REQUEST(.variant = "Small", .width = W, .height = W, .spp = 4,
                                       .in_dtype = HFC_F32, .features = in,
                                       .out_dtype = HFC_F32,
                                       .result = out + (size_t)(k * WINDOW + i) * W * W * 3);
          assert_int_equal(hfc_submit(c[k], &r, NULL), 0);
        }
      for (int k = 0; k < clients; k++)
        for (int i = 0; i < WINDOW; i++) {
          hfc_completion done;
          assert_int_equal(hfc_wait(c[k], 60000, &done), 0);
          if (done.status)
            fail_msg("%d client(s), round %d: %s (%s)", clients, round,
                     hfc_strerror(done.status), hfc_last_message(c[k]));
        }
    }
    for (int k = 0; k < clients; k++) hfc_close(c[k]);
    assert_int_equal(server_stop(&d, 20000), 0);
  }
  free(out);
  free(in);
}

/* Item: the queue is shared (docs/SERVER.md, "Limits and backpressure"); here
 * by connection (--queue-share-by connection), as the connections are one
 * process's (test_queue_share_per_client.py has clients). Three
 * connections keep their windows full, resending at once after every reply;
 * with --queue-size 8 and 4 in flight each they could hold 12 frames, so
 * first come first served would leave a client that sends one frame every
 * 20 ms almost nothing but BUSY. The queue's last quarter goes only to
 * connections under their share (8 / n); when hogs that dipped under
 * theirs took it, a frame of the hog holding the most is pushed out. So the
 * polite client, holding none, is never refused: 8 queued frames among 3
 * hogs put at least 3, over any share, on one of them. */
static void test_queue_shared(void **state) {
  (void)state;
  const char *extra[] = {"--queue-size", "8", "--max-inflight", "4", "--max-batch", "1",
                         "--queue-share-by", "connection", NULL};
  server d;
  if (server_start(&H, &d, extra)) fail_msg("daemon did not start");
  atomic_int stop = 0;
  hog hogs[3];
  pthread_t th[3];
  for (int k = 0; k < 3; k++) {
    hogs[k] = (hog){.d = &d, .stop = &stop};
    assert_int_equal(pthread_create(&th[k], NULL, hog_main, &hogs[k]), 0);
  }
  usleep(300 * 1000);  /* the hogs fill the queue */
  hfc_client *c = client_connect(&d, "polite");
  assert_non_null(c);
  enum { N = 20, W = 16 };
  float *in = make_features(W, W, 4, 9), *out = malloc((size_t)W * W * 3 * sizeof *out);
  int busy = 0, served = 0;
  for (int i = 0; i < N; i++) {
    hfc_request r = TEST_REQUEST(.variant = "Small", .width = W, .height = W, .spp = 4,
                                 .in_dtype = HFC_F32, .features = in, .out_dtype = HFC_F32,
                                 .result = out);
    int rc = hfc_filter(c, &r, NULL);
    if (rc == HFC_E_BUSY) busy++;
    else if (rc == 0) served++;
    else fail_msg("polite frame %d: %s (%s)", i, hfc_strerror(rc), hfc_last_message(c));
    usleep(20 * 1000);
  }
  atomic_store(&stop, 1);
  for (int k = 0; k < 3; k++) pthread_join(th[k], NULL);
  hfc_close(c);
  free(in);
  free(out);
  int hog_busy = hogs[0].busy + hogs[1].busy + hogs[2].busy;
  printf("polite client: %d served, %d BUSY of %d; hogs: %d, %d, %d served, %d BUSY\n", served,
         busy, N, hogs[0].served, hogs[1].served, hogs[2].served, hog_busy);
  for (int k = 0; k < 3; k++) assert_false(hogs[k].failed);
  assert_true(hog_busy > 0);        /* the queue was contended */
  assert_int_equal(served, N);
  assert_int_equal(server_stop(&d, 20000), 0);
}

/* Item: the default --max-size is Ultra HD, 3840x2160, lowered keeping its
 * 16:9 aspect: a tight budget still admits engine frames of that shape
 * (1920x1080 with the bundled variants and the default budget), where a
 * square default would cut their width to their height. */
static void test_default_size_is_landscape(void **state) {
  (void)state;
  server d;
  const char *args[] = {"--max-memory-mb", "64", NULL};
  assert_int_equal(server_start(&H, &d, args), 0);
  hfc_client *c = NULL;
  hfc_options o = test_options("limits", NULL, 20000);
  assert_int_equal(hfc_connect(d.unix_url, &o, &c), 0);
  const hfc_server_info *i = hfc_info(c);
  int W = i->max_width, HH = i->max_height;
  printf("announced %dx%d\n", W, HH);
  assert_true(W > 16 && W < 3840);
  assert_int_equal(HH, (int)((int64_t)W * 2160 / 3840));   /* the default's aspect */
  assert_true(server_log_has(&d, "max size lowered from 3840x2160"));
  /* A reload derives the size again, and says nothing when it is the same. */
  kill(d.pid, SIGHUP);
  for (int waited = 0; waited < 20000 && !server_log_has(&d, "reload done"); waited += 20)
    usleep(20000);
  assert_true(server_log_has(&d, "reload done"));
  assert_int_equal(server_log_count(&d, "max size lowered"), 1);
  hfc_close(c);
  assert_int_equal(server_stop(&d, 20000), 0);
}

/* Item: HELLO_OK announces a size a frame can meet. With a 1 MiB frame
 * limit and 4 MiB of memory, 4096x4096 is lowered; a frame of every
 * variant at exactly the announced size (f32, composite: the largest) is
 * served, and a pixel more is refused as TOO_LARGE, non-fatal. */
static void test_announced_maximum_is_admitted(void **state) {
  (void)state;
  server d;
  const char *args[] = {"--max-size", "4096x4096", "--max-frame-mb", "1", "--max-memory-mb",
                        "4", NULL};
  assert_int_equal(server_start(&H, &d, args), 0);
  hfc_client *c = NULL;
  hfc_options o = test_options("limits", NULL, 20000);
  assert_int_equal(hfc_connect(d.unix_url, &o, &c), 0);
  const hfc_server_info *i = hfc_info(c);
  int W = i->max_width, HH = i->max_height;
  printf("announced %dx%d, max_frame_bytes %llu\n", W, HH,
         (unsigned long long)i->max_frame_bytes);
  assert_true(W > 16 && W < 4096);
  assert_int_equal(W, HH);   /* the configured aspect */
  assert_int_equal(i->max_frame_bytes, 1u << 20);
  assert_true(server_log_has(&d, "max size lowered from 4096x4096"));
  /* the announced size fits the announced payload limit */
  uint64_t feat;
  assert_int_equal(hfp_features_bytes((uint32_t)W, (uint32_t)HH, (uint32_t)i->max_spp, HFP_F32,
                                      &feat), 0);
  assert_true(HFP_FILTER_FIXED + 5 + feat <= i->max_frame_bytes);
  hfc_close(c);

  int fd = raw_connect(d.unix_url);
  assert_int_equal(raw_hello(fd, NULL), 0);
  int code;
  const char *names[] = {"Small", "Tiny", "Mono"};
  uint32_t id = 1;
  for (int k = 0; k < 3; k++) {
    if (filter_once(fd, id++, names[k], W, HH, 1, &code) != HFP_RESULT)
      fail_msg("%s at the announced %dx%d: %s", names[k], W, HH, hfp_code_name(code));
  }
  assert_int_equal(filter_once(fd, id++, "Small", W + 1, HH, 0, &code), HFP_ERROR);
  assert_int_equal(code, HFP_E_TOO_LARGE);
  assert_int_equal(filter_once(fd, id++, "Mono", W, HH + 1, 0, &code), HFP_ERROR);
  assert_int_equal(code, HFP_E_TOO_LARGE);
  /* still the same connection */
  assert_int_equal(filter_once(fd, id++, "Tiny", 8, 8, 0, &code), HFP_RESULT);
  close(fd);
  assert_int_equal(server_stop(&d, 20000), 0);

}

/* The announced size is admitted on an idle server whatever the worker
 * keeps: frames of the bundled Base and KernelAC at it (f32, composite), one
 * variant after the other at --max-memory-mb 64, where Base's kept plans
 * fill the quarter they may use and a frame's socket buffers are rounded up
 * to 2 MiB (before, the third frame was BUSY for good: 0.3 MiB over). */
static void test_announced_maximum_after_other_plans(void **state) {
  (void)state;
  server d;
#ifdef HF_HAVE_ONEDNN
  const char *backend = "cpu";   /* the backend that keeps plans */
#else
  const char *backend = "cpu-ref";
#endif
  char empty[300];
  snprintf(empty, sizeof empty, "%s/no-weights", H.dir);
  assert_int_equal(mkdir(empty, 0700), 0);
  const char *args[] = {"--weights-dir", empty, "--weights", HF_SOURCE_DIR "/weights/base.safetensors",
                        "--weights", HF_SOURCE_DIR "/weights/kernel_ac.safetensors",
                        "--backend", backend, "--max-memory-mb", "64", NULL};
  assert_int_equal(server_start(&H, &d, args), 0);
  hfc_client *c = NULL;
  hfc_options o = test_options("plans", NULL, 60000);
  assert_int_equal(hfc_connect(d.unix_url, &o, &c), 0);
  const int W = hfc_info(c)->max_width, HH = hfc_info(c)->max_height;
  const size_t px = (size_t)W * HH;
  float *in = make_features(W, HH, 4, 5), *est = calloc(px * 3, sizeof(float));
  float *out = malloc(px * 3 * sizeof(float)), *rgba = malloc(px * 4 * sizeof(float));
  assert_true(in && est && out && rgba);
  const char *order[] = {"KernelAC", "Base", "KernelAC", "Base", "KernelAC"};
  for (int k = 0; k < 5; k++) {
    const int ac = order[k][0] == 'K';
    hfc_request r = TEST_REQUEST(.variant = order[k], .width = W, .height = HH, .spp = 4,
                                  .features = in, .result = out, .rgba = rgba,
                                  .hair = {0.3f, 0.2f, 0.1f}, .light = {1, 1, 1},
                                  .estimate = ac, .estimate_buffer = ac ? est : NULL);
    int rc = hfc_filter(c, &r, NULL);
    if (rc) fail_msg("%s at the announced %dx%d, frame %d: %s (%s)", order[k], W, HH, k + 1,
                     hfc_strerror(rc), hfc_last_message(c));
  }
  printf("%s, --max-memory-mb 64: Base and KernelAC in turn at the announced %dx%d\n", backend,
         W, HH);
  free(in), free(est), free(out), free(rgba);
  hfc_close(c);
  assert_int_equal(server_stop(&d, 20000), 0);
}

/* Item: a shared segment larger than the whole budget is TOO_LARGE (no
 * retry helps); one larger than what is left is BUSY (a retry may). */
static void test_segment_too_large_vs_busy(void **state) {
  (void)state;
  server d;
  const char *args[] = {"--max-shm-mb", "1", NULL};
  assert_int_equal(server_start(&H, &d, args), 0);
  hfc_client *c = NULL;
  hfc_options o = test_options("shm", NULL, 20000);
  assert_int_equal(hfc_connect(d.unix_url, &o, &c), 0);
  void *a = NULL, *b = NULL;
  assert_int_equal(hfc_shm_alloc(c, 768 << 10, &a), 0);
  assert_int_equal(hfc_shm_alloc(c, 768 << 10, &b), HFC_E_BUSY);
  assert_int_equal(hfc_shm_alloc(c, (1 << 20) + 1, &b), HFC_E_TOO_LARGE);
  assert_non_null(strstr(hfc_last_message(c), "larger than the whole shared-memory budget"));
  assert_int_equal(hfc_shm_free(c, a), 0);
  /* what was BUSY now fits */
  assert_int_equal(hfc_shm_alloc(c, 768 << 10, &b), 0);
  assert_int_equal(hfc_shm_free(c, b), 0);
  hfc_close(c);
  assert_int_equal(server_stop(&d, 20000), 0);
}

/* Item: six connections that announce the largest frame and send only its
 * first bytes hold only those bytes: an 8x8 frame from someone else is
 * served. When all six then send the rest, the budget still holds: some
 * are refused BUSY (while receiving), the others served. */
static void test_memory_charged_as_received(void **state) {
  (void)state;
  server d;
  const char *args[] = {"--max-memory-mb", "8", "--max-size", "4096x4096", NULL};
  assert_int_equal(server_start(&H, &d, args), 0);
  hfc_client *c = NULL;
  hfc_options o = test_options("probe", NULL, 20000);
  assert_int_equal(hfc_connect(d.unix_url, &o, &c), 0);
  int W = hfc_info(c)->max_width, HH = hfc_info(c)->max_height;
  enum { M = 6 };
  float *in = make_features(W, HH, 4, 9);
  size_t len;
  uint8_t *f = raw_filter(1, "Small", W, HH, 4, in, &len);
  int fd[M];
  for (int i = 0; i < M; i++) {
    fd[i] = raw_connect(d.unix_url);
    assert_int_equal(raw_hello(fd[i], NULL), 0);
    hfp_put_u32(f + 8, (uint32_t)i + 1);
    assert_int_equal(raw_send(fd[i], f, 4096), 0);
  }
  usleep(100000);
  float small_in[8 * 8 * 24], small_out[8 * 8 * 3];
  memset(small_in, 0, sizeof small_in);
  hfc_request r = TEST_REQUEST(.variant = "Small", .width = 8, .height = 8, .spp = 4, .in_dtype = HFC_F32,
                   .features = small_in, .out_dtype = HFC_F32, .result = small_out);
  int rc = hfc_filter(c, &r, NULL);
  if (rc) fail_msg("8x8 frame beside six announced ones: %s (%s)", hfc_strerror(rc),
                   hfc_last_message(c));
  hfc_close(c);
  int served = 0, busy = 0;
  /* A frame refused while it arrives is read to its end and dropped, so
   * every send completes. */
  for (int i = 0; i < M; i++) assert_int_equal(raw_send(fd[i], f + 4096, len - 4096), 0);
  for (int i = 0; i < M; i++) {
    hfp_header h;
    uint8_t *p;
    assert_int_equal(raw_read(fd[i], &h, &p), 0);
    assert_int_equal(h.request_id, (uint32_t)i + 1);
    if (h.type == HFP_RESULT) {
      served++;
    } else {
      hfp_error e;
      assert_int_equal(h.type, HFP_ERROR);
      assert_int_equal(hfp_decode_error(p, h.length, &e), 0);
      assert_int_equal(e.code, HFP_E_BUSY);
      assert_int_equal(e.fatal, 0);
      busy++;
    }
    free(p);
    close(fd[i]);
  }
  printf("six %dx%d frames in 8 MiB: %d served, %d BUSY\n", W, HH, served, busy);
  assert_true(served >= 1);
  assert_true(busy >= 1);
  free(f);
  free(in);
  assert_true(server_alive(&d));
  assert_int_equal(server_stop(&d, 20000), 0);
}

/* Item: peers that send the head and the first 64 KiB of a frame large
 * enough for a receive-pool buffer (1 MiB and up) and then stop hold those
 * bytes, not the whole buffer: a frame of the announced maximum from
 * someone else is served beside three of them. */
static void test_slow_senders_hold_what_they_sent(void **state) {
  (void)state;
  server d;
  const char *args[] = {"--max-memory-mb", "64", NULL};
  assert_int_equal(server_start(&H, &d, args), 0);
  hfc_client *c = NULL;
  hfc_options o = test_options("probe", NULL, 60000);
  assert_int_equal(hfc_connect(d.unix_url, &o, &c), 0);
  int W = hfc_info(c)->max_width, HH = hfc_info(c)->max_height;
  enum { M = 3 };
  float *in = make_features(W, HH, 4, 10);
  size_t len;
  uint8_t *f = raw_filter(1, "Small", W, HH, 4, in, &len);
  assert_true(len > ((size_t)2 << 20));
  int fd[M];
  for (int i = 0; i < M; i++) {
    fd[i] = raw_connect(d.unix_url);
    assert_int_equal(raw_hello(fd[i], NULL), 0);
    assert_int_equal(raw_send(fd[i], f, 65536), 0);
  }
  usleep(200000);
  float *out = malloc(sizeof(float) * 3 * (size_t)W * HH);
  assert_non_null(out);
  hfc_request r = TEST_REQUEST(.variant = "Small", .width = W, .height = HH, .spp = 4,
                   .in_dtype = HFC_F32, .features = in, .out_dtype = HFC_F32, .result = out);
  int rc = hfc_filter(c, &r, NULL);
  if (rc) fail_msg("%dx%d frame beside %d peers that sent 64 KiB of one: %s (%s)", W, HH, M,
                   hfc_strerror(rc), hfc_last_message(c));
  hfc_close(c);
  for (int i = 0; i < M; i++) close(fd[i]);
  free(out);
  free(f);
  free(in);
  assert_true(server_alive(&d));
  assert_int_equal(server_stop(&d, 20000), 0);
}

/* The per-variant cache_bytes of the daemon at url (STATS, version 2,
 * through hfc_get_stats), summed; -1 on any error. */
static long long stats_cache_bytes(const char *url, int *variants) {
  hfc_options o = test_options("limits-stats", NULL, 20000);
  hfc_client *c = NULL;
  if (hfc_connect(url, &o, &c)) return -1;
  static hfc_stats st;
  long long sum = -1;
  if (!hfc_get_stats(c, &st)) {
    sum = 0;
    for (int i = 0; i < st.num_variants; i++) {
      printf("  STATS %s: cache_bytes %.1f MiB, %llu served\n", st.variants[i].name,
             st.variants[i].cache_bytes / 1048576.0, (unsigned long long)st.variants[i].requests_ok);
      sum += (long long)st.variants[i].cache_bytes;
    }
    *variants = st.num_variants;
  }
  hfc_close(c);
  return sum;
}

/* Item: inference memory is inside --max-memory-mb. Four frames at the
 * announced maximum sent at once: the daemon's peak resident memory grows
 * by no more than the budget (those that do not fit are BUSY), and once
 * they are answered what they needed is given back. On the cpu backend
 * when built (its plans are what could stay), else cpu-ref. */
static void test_inference_memory_in_budget(void **state) {
  (void)state;
  server d;
#ifdef HF_HAVE_ONEDNN
  const char *backend = "cpu";
#else
  const char *backend = "cpu-ref";
#endif
  const char *args[] = {"--max-memory-mb", "48", "--max-size", "4096x4096", "--backend",
                        backend, "--max-batch", "4", NULL};
  assert_int_equal(server_start(&H, &d, args), 0);
  hfc_client *c = NULL;
  hfc_options o = test_options("memory", NULL, 60000);
  assert_int_equal(hfc_connect(d.unix_url, &o, &c), 0);
  int W = hfc_info(c)->max_width, HH = hfc_info(c)->max_height;
  /* Warm up on a small frame: threads started, small plans made. */
  float small_in[8 * 8 * 24] = {0}, small_out[8 * 8 * 3];
  hfc_request sr = TEST_REQUEST(.variant = "Small", .width = 8, .height = 8, .spp = 4, .in_dtype = HFC_F32,
                    .features = small_in, .out_dtype = HFC_F32, .result = small_out);
  assert_int_equal(hfc_filter(c, &sr, NULL), 0);
  int rss_ok = !UNDER_ASAN && proc_reset_peak(d.pid) == 0;
  int nv = 0;
  long long kept0 = stats_cache_bytes(d.unix_url, &nv);
  long rss0 = proc_status_kb(d.pid, "VmRSS");
  burst b = send_burst(c, W, HH, 4);
  int served = b.served, busy = b.busy;
  long hwm = proc_status_kb(d.pid, "VmHWM");
  /* The plans and buffers of the large frames are freed; a small frame
   * (whose plan may stay) shows the daemon still serves. */
  assert_int_equal(hfc_filter(c, &sr, NULL), 0);
  long rss1 = proc_status_kb(d.pid, "VmRSS");
  long long kept1 = stats_cache_bytes(d.unix_url, &nv);
  printf("%s, %dx%d frames, --max-memory-mb 48: %d served, %d BUSY; RSS %.1f MiB before, "
         "peak +%.1f MiB, %.1f MiB after, of which plans kept %.1f MiB more\n", backend, W, HH,
         served, busy, rss0 / 1024.0, (hwm - rss0) / 1024.0, rss1 / 1024.0,
         (kept1 - kept0) / 1048576.0);
  assert_true(served >= 1);
  if (rss_ok) {
    /* Inside the budget (the 8x8 frame's plan and connection buffers are in
     * the 2 MiB). */
    assert_true(hwm - rss0 <= 48 * 1024 + 2048);
    /* Given back: what stays is at most the quarter of the budget the
     * daemon may keep between runs (12 MiB: plans, idle receive buffers)
     * and the malloc arenas and thread state such a burst leaves (5 MiB),
     * less than the burst took at its peak. Measured: +3.5 to 4.3 MiB at
     * 240x240 frames, +8.9 MiB at 236x236 (the same with the accounting
     * before 2 MiB receive steps were counted in a frame's need, whose
     * announced size was 240x240), the plans STATS reports unchanged. */
    assert_true(kept0 >= 0 && kept1 >= 0 && kept1 <= 12LL << 20);
    assert_true(rss1 - rss0 <= 5120 + 12 * 1024);
  } else {
    printf("peak RSS not checked: %s\n",
           UNDER_ASAN ? "AddressSanitizer keeps freed memory" : "cannot reset it");
  }
  hfc_close(c);
  assert_int_equal(server_stop(&d, 20000), 0);
}

/* Item: the daemon's working memory as a whole (request and result
 * buffers, inference, the backend's plans and the receive buffers kept for
 * reuse) stays inside --max-memory-mb under a mixed load: every variant,
 * seven sizes from 40x24 to the largest the budget admits, float32 and
 * float16, four frames in flight, three rounds so that plans and buffers
 * are kept, reused and evicted. The peak resident memory grows by no more than the limit over
 * where it was once the models were loaded; what the variants keep between
 * runs, as STATS reports it, is within the quarter of the limit set aside
 * for it. */
static void test_mixed_load_within_budget(void **state) {
  (void)state;
  server d;
#ifdef HF_HAVE_ONEDNN
  const char *backend = "cpu";
#else
  const char *backend = "cpu-ref";
#endif
  enum { LIMIT_MB = 64, INFLIGHT = 4 };
  char limit[16];
  snprintf(limit, sizeof limit, "%d", LIMIT_MB);
  const char *args[] = {"--max-memory-mb", limit, "--max-size", "1024x1024", "--backend",
                        backend, "--max-batch", "4", NULL};
  assert_int_equal(server_start(&H, &d, args), 0);
  hfc_client *c = NULL;
  hfc_options o = test_options("mixed", NULL, 60000);
  assert_int_equal(hfc_connect(d.unix_url, &o, &c), 0);
  int rss_ok = !UNDER_ASAN && proc_reset_peak(d.pid) == 0;
  long rss0 = proc_status_kb(d.pid, "VmRSS");
  /* Up to the largest frame the daemon admits in this budget (it lowers
   * --max-size to that and announces it), and odd shapes below it. */
  const int W = hfc_info(c)->max_width, HH = hfc_info(c)->max_height;
  const int sizes[][2] = {{40, 24},        {W / 4, HH / 4}, {W / 2, HH / 2},     {W, HH},
                          {W * 2 / 3, HH / 3}, {W / 5, HH}, {W / 3 + 7, HH / 2 + 3}};
  const int nsizes = (int)(sizeof sizes / sizeof sizes[0]);
  int busy = 0, sent = 0, pending = 0;
  /* The frames in flight: their id and buffers (completions may come in
   * another order than the frames went, batches taking later frames). */
  typedef struct {
    uint32_t id;
    void *in, *out;
    hfc_request r;
  } frame;
  frame fl[INFLIGHT];
  memset(fl, 0, sizeof fl);
  /* Frames that came back BUSY: sent again, alone, once the load is done,
   * so that every frame of the mix is served whatever the machine's speed. */
  frame *again = calloc(4 * (size_t)nsizes * (size_t)H.nv, sizeof *again);
  int nagain = 0;
  assert_non_null(again);
  for (int round = 0; round <= 3; round++)
    for (int si = 0; si < nsizes; si++)
      for (int vi = 0; vi < H.nv; vi++) {
        const int last = round == 3;
        if (pending == INFLIGHT || (last && pending)) {
          hfc_completion done;
          assert_int_equal(hfc_wait(c, 60000, &done), 0);
          pending--;
          if (done.status && done.status != HFC_E_BUSY)
            fail_msg("frame %u: %s", done.id, hfc_strerror(done.status));
          for (int k = 0; k < INFLIGHT; k++)
            if (fl[k].in && fl[k].id == done.id) {
              if (done.status == HFC_E_BUSY) {
                busy++;
                again[nagain++] = fl[k]; /* keeps its buffers */
              } else {
                free(fl[k].in), free(fl[k].out);
              }
              fl[k].in = fl[k].out = NULL;
            }
        }
        if (last) continue; /* the fourth pass only collects */
        int slot = 0;
        while (fl[slot].in) slot++;
        const int w = sizes[si][0], h = sizes[si][1], spp = H.v[vi].cfg.spp;
        const int f16 = (round + si + vi) & 1;
        float *feat = make_features(w, h, spp, (uint32_t)sent);
        size_t nin = (size_t)w * h * spp * HF_FEATURES_PER_SAMPLE;
        if (f16) {
          fl[slot].in = malloc(nin * sizeof(uint16_t));
          hf_f32_to_f16_array(feat, fl[slot].in, nin);
          free(feat);
        } else {
          fl[slot].in = feat;
        }
        fl[slot].out = malloc((size_t)w * h * 3 * sizeof(float));
        hfc_request r = TEST_REQUEST(.variant = H.v[vi].cfg.name, .width = w, .height = h,
                                     .spp = spp, .in_dtype = f16 ? HFC_F16 : HFC_F32,
                                     .features = fl[slot].in, .out_dtype = f16 ? HFC_F16 : HFC_F32,
                                     .result = fl[slot].out);
        fl[slot].r = r;
        assert_int_equal(hfc_submit(c, &fl[slot].r, &fl[slot].id), 0);
        sent++, pending++;
      }
  assert_int_equal(pending, 0);
  /* Alone, each of them must be admitted: it is no larger than the daemon
   * announced. A frame's charge is returned when its reply has gone, which
   * may be a moment after the client has it, so a BUSY here is tried again
   * a few times before it counts as a failure. */
  for (int k = 0; k < nagain; k++) {
    int status = HFC_E_BUSY;
    for (int attempt = 0; attempt < 20 && status == HFC_E_BUSY; attempt++) {
      if (attempt) usleep(50000);
      hfc_completion done;
      assert_int_equal(hfc_submit(c, &again[k].r, &again[k].id), 0);
      assert_int_equal(hfc_wait(c, 60000, &done), 0);
      assert_int_equal(done.id, again[k].id);
      status = done.status;
    }
    if (status)
      fail_msg("a %dx%d %s frame, sent alone: %s", again[k].r.width, again[k].r.height,
               again[k].r.variant, hfc_strerror(status));
    free(again[k].in), free(again[k].out);
  }
  free(again);
  long hwm = proc_status_kb(d.pid, "VmHWM");
  int nvar = 0;
  long long cached = stats_cache_bytes(d.unix_url, &nvar);
  printf("%s, %d frames of %d variants x %d sizes up to %dx%d, f32 and f16, %d in flight, "
         "--max-memory-mb %d: %d BUSY and then served alone; RSS %.1f MiB with the models loaded, peak +%.1f MiB; "
         "kept between runs %.1f MiB\n", backend, sent, H.nv, nsizes, W, HH, INFLIGHT, LIMIT_MB, busy, rss0 / 1024.0,
         (hwm - rss0) / 1024.0, cached / 1048576.0);
  assert_int_equal(nvar, H.nv);
  assert_true(cached >= 0 && cached <= (long long)LIMIT_MB * 1048576 / 4);
  if (rss_ok)
    assert_true(hwm - rss0 <= LIMIT_MB * 1024);
  else
    printf("peak RSS not checked: %s\n",
           UNDER_ASAN ? "AddressSanitizer keeps freed memory" : "cannot reset it");
  hfc_close(c);
  assert_true(server_alive(&d));
  assert_int_equal(server_stop(&d, 20000), 0);
}

/* Batching still happens under the memory bound: frames whose gathered
 * inputs are megabytes are run together when they were charged enough for
 * it, which each frame is (its slot in a batch is part of its charge). */
static void test_batches_form_within_budget(void **state) {
  (void)state;
  server d;
  const char *args[] = {"--max-memory-mb", "512", "--max-batch", "4", "--max-queue-delay-us",
                        "500000", NULL};
  assert_int_equal(server_start(&H, &d, args), 0);
  hfc_client *c = NULL;
  hfc_options o = test_options("batch", NULL, 60000);
  assert_int_equal(hfc_connect(d.unix_url, &o, &c), 0);
  burst b = send_burst(c, 256, 256, 4);
  assert_int_equal(b.served, 4);
  assert_true(b.max_batch > 1);
  hfc_close(c);
  assert_int_equal(server_stop(&d, 20000), 0);
}

/* STATS' queue_depth, asked on c. */
static int queue_depth(hfc_client *c) {
  static hfc_stats st;
  assert_int_equal(hfc_get_stats(c, &st), 0);
  return st.queue_depth;
}

/* Waits up to 2 s for STATS' queue_depth to be want; fails saying what it
 * was. */
static void expect_queue_depth(hfc_client *c, int want, const char *what) {
  int got = -1;
  for (int waited = 0; waited < 2000; waited += 10) {
    if ((got = queue_depth(c)) == want) return;
    usleep(10000);
  }
  fail_msg("queue_depth %d with %s, not %d", got, what, want);
}

/* n raw connections to d's Unix socket, each past its HELLO. */
static void raw_clients(const server *d, int *fd, int n) {
  for (int k = 0; k < n; k++) {
    fd[k] = raw_connect(d->unix_url);
    assert_true(fd[k] >= 0);
    assert_int_equal(raw_hello(fd[k], NULL), 0);
  }
}

/* Sends a FILTER of Small at w x h with id on fd. */
static void send_small(int fd, uint32_t id, int w, int h) {
  float *in = make_features(w, h, 4, id);
  size_t len;
  uint8_t *f = raw_filter(id, "Small", w, h, 4, in, &len);
  assert_non_null(f);
  assert_int_equal(raw_send(fd, f, len), 0);
  free(f);
  free(in);
}

/* Item: frames the batcher holds while it waits for partners are queued
 * frames like any other (docs/SERVER.md, "Limits and backpressure",
 * "Batching"; PROTOCOL.md, STATS' queue_depth: admitted, not yet running).
 * With --queue-size 8, --max-batch 16 and a delay of 10 s, four frames from
 * one connection and two from another wait in the batcher: STATS says 6;
 * the first connection's fifth frame would take a place in the queue's
 * last quarter over its share (8 / 2), so it is BUSY; two frames from a
 * third connection fill the queue, and then no partner can be admitted, so
 * the batch of 8 runs at once rather than when the 10 s are up. The
 * connections are one process's: shares by connection. */
static void test_batcher_frames_are_queued(void **state) {
  (void)state;
  enum { W = 24 };
  server d;
  const char *args[] = {"--queue-size", "8", "--max-batch", "16", "--max-queue-delay-us",
                        "10000000", "--queue-share-by", "connection", NULL};
  hfc_client *c;
  assert_int_equal(server_start_connected(&H, &d, args, "stats", &c), 0);
  int fd[3];
  raw_clients(&d, fd, 3);
  for (uint32_t id = 1; id <= 4; id++) send_small(fd[0], id, W, W);
  expect_queue_depth(c, 4, "4 frames in the batcher");
  for (uint32_t id = 1; id <= 2; id++) send_small(fd[1], id, W, W);
  expect_queue_depth(c, 6, "6 frames in the batcher");
  int code = 0;
  hfp_result r;
  uint8_t *p;
  send_small(fd[0], 5, W, W);
  if (read_reply(fd[0], 5, &code, &r, &p) != HFP_ERROR)
    fail_msg("a fifth frame over its share of a queue holding 6 of 8 was admitted");
  free(p);
  assert_int_equal(code, HFP_E_BUSY);
  expect_queue_depth(c, 6, "6 frames in the batcher and one refused");
  for (uint32_t id = 1; id <= 2; id++) send_small(fd[2], id, W, W);
  const int sent[3] = {4, 2, 2};
  for (int k = 0; k < 3; k++)
    for (uint32_t id = 1; id <= (uint32_t)sent[k]; id++) {
      assert_int_equal(read_reply(fd[k], id, &code, &r, &p), HFP_RESULT);
      free(p);
      if (r.batch != 8 || r.timing.queue_us >= 5000000)
        fail_msg("connection %d frame %u: batch %u, queued %.3f s; want the 8 frames that "
                 "filled the queue run together at once", k, id, r.batch,
                 r.timing.queue_us / 1e6);
    }
  expect_queue_depth(c, 0, "every frame answered");
  for (int k = 0; k < 3; k++) close(fd[k]);
  hfc_close(c);
  assert_int_equal(server_stop(&d, 20000), 0);
}

/* Item: a frame past its budget gives its memory back as soon as it is
 * found expired (docs/SERVER.md, "Deadlines"), not when the worker next
 * forms a batch. A small frame waits 3 s in the batcher for a partner; a
 * frame of the announced maximum with a budget of 50 ms queues behind it
 * and its budget passes; then another frame of the announced maximum,
 * without a budget, comes from another connection. Two such frames do not
 * fit --max-memory-mb together: the expired one is answered EXPIRED and
 * the new one admitted and served, not refused BUSY for memory a frame
 * that will never run holds. */
static void test_expired_frame_gives_back_memory(void **state) {
  (void)state;
  server d;
  const char *args[] = {"--max-memory-mb", "48", "--max-size", "4096x4096", "--max-batch", "16",
                        "--max-queue-delay-us", "3000000", NULL};
  hfc_client *c;
  assert_int_equal(server_start_connected(&H, &d, args, "stats", &c), 0);
  int W = hfc_info(c)->max_width, HH = hfc_info(c)->max_height;
  int fd0 = connect_versions_or_fail(d.unix_url, 4, 4), fd1;
  raw_clients(&d, &fd1, 1);
  send_small(fd0, 1, 8, 8);
  expect_queue_depth(c, 1, "a frame in the batcher");
  float *in = make_features(W, HH, 4, 2);
  size_t len;
  uint8_t *f = raw_filter_budget(2, "Small", W, HH, 4, in, 50000, &len);
  assert_non_null(f);
  assert_int_equal(raw_send(fd0, f, len), 0);
  expect_queue_depth(c, 2, "a frame of the announced maximum queued behind it");
  usleep(200000);   /* its 50 ms budget passes */
  free(f);
  f = raw_filter(3, "Small", W, HH, 4, in, &len);
  assert_non_null(f);
  assert_int_equal(raw_send(fd1, f, len), 0);
  hfp_header h;
  uint8_t *p;
  assert_int_equal(raw_read(fd1, &h, &p), 0);
  assert_int_equal(h.request_id, 3);
  if (h.type == HFP_ERROR) {
    hfp_error e;
    assert_int_equal(hfp_decode_error(p, h.length, &e), 0);
    fail_msg("a %dx%d frame refused beside an expired one of that size: %s", W, HH, e.message);
  }
  assert_int_equal(h.type, HFP_RESULT);
  hfp_result r;
  assert_int_equal(hfp_decode_result(p, h.length, &r), 0);
  assert_int_equal(r.status, HFP_OK);
  free(p);
  int code;
  int seen = 0;
  for (int k = 0; k < 2; k++) {
    assert_int_equal(raw_read(fd0, &h, &p), 0);
    assert_int_equal(h.type, HFP_RESULT);
    assert_int_equal(hfp_decode_result(p, h.length, &r), 0);
    code = r.status;
    assert_int_equal(code, h.request_id == 2 ? HFP_E_EXPIRED : HFP_OK);
    seen |= 1 << h.request_id;
    free(p);
  }
  assert_int_equal(seen, (1 << 1) | (1 << 2));
  close(fd0);
  close(fd1);
  free(f);
  free(in);
  hfc_close(c);
  assert_int_equal(server_stop(&d, 20000), 0);
}

/* hairfilterd_request_memory_bytes of d's /metrics; fails when absent. */
static double request_memory(const server *d) {
  char *m = http_get(d, "/metrics");
  assert_non_null(m);
  const char *at = strstr(m, "\nhairfilterd_request_memory_bytes ");
  if (!at) fail_msg("no hairfilterd_request_memory_bytes in /metrics:\n%s", m);
  double v = strtod(at + strlen("\nhairfilterd_request_memory_bytes "), NULL);
  free(m);
  return v;
}

/* Sends a FILTER of Small at w x h with a composite (and budget_us, 0:
 * none) with id on fd. */
static void send_composite(int fd, uint32_t id, int w, int h, uint32_t budget_us) {
  float *in = make_features(w, h, 4, id);
  size_t len;
  uint8_t *f = raw_filter_budget(id, "Small", w, h, 4, in, budget_us, &len);
  assert_non_null(f);
  uint8_t *flags = f + HFP_HEADER_SIZE + 2;
  hfp_put_u16(flags, (uint16_t)(hfp_get_u16(flags) | HFP_FILTER_COMPOSITE));
  assert_int_equal(raw_send(fd, f, len), 0);
  free(f);
  free(in);
}

/* Item: a frame answered without a tensor (EXPIRED here) gives its
 * buffers back as it is answered, not once its RESULT has been written
 * (docs/SERVER.md, "Deadlines"). A client that reads nothing gets two
 * results with composites, which back up on its connection; then its
 * 512x512 frame with a composite and a budget of 1 s queues behind a
 * frame the batcher holds for 5 s and expires, its RESULT waiting behind
 * the two unwritten ones. The memory charged is below that frame's 7 MiB
 * of result buffers all the same: what is left is the two results (900
 * KiB) and the held 8x8 frame. */
static void test_unrun_frame_gives_back_buffers(void **state) {
  (void)state;
  server d;
  const char *args[] = {"--max-batch", "2", "--max-queue-delay-us", "5000000", "--http",
                        "tcp:127.0.0.1:0", NULL};
  hfc_client *c;
  assert_int_equal(server_start_connected(&H, &d, args, "stats", &c), 0);
  int a = raw_connect_rcvbuf(d.unix_url, 4096), b;
  assert_true(a >= 0);
  assert_int_equal(raw_hello_versions(a, NULL, 4, 4), 0);
  raw_clients(&d, &b, 1);
  /* A batch of two (--max-batch) runs at once; its 900 KiB of results
   * fill a's socket buffers, and a reads none. */
  send_composite(a, 1, 128, 128, 0);
  send_composite(a, 2, 128, 128, 0);
  expect_queue_depth(c, 0, "the two frames run");
  send_small(b, 1, 8, 8);
  expect_queue_depth(c, 1, "a frame in the batcher");
  send_composite(a, 3, 512, 512, 1000000);
  expect_queue_depth(c, 2, "the 512x512 frame queued behind it");
  expect_queue_depth(c, 1, "the 512x512 frame answered EXPIRED");
  /* 512x512 with a composite: 3 MiB of result and 4 MiB of composite */
  const double results = 512.0 * 512 * 7 * 4;
  double now = request_memory(&d);
  for (int waited = 0; waited < 2000 && now >= results / 2; waited += 10) {
    usleep(10000);
    now = request_memory(&d);
  }
  printf("memory charged once the 512x512 frame expired: %.2f MiB\n", now / 1048576);
  if (now >= results / 2)
    fail_msg("the expired frame's %.0f MiB of result buffers are still charged (%.2f MiB in "
             "all) while its RESULT waits to be written", results / 1048576, now / 1048576);
  close(a);
  hfp_header h;
  uint8_t *p;
  assert_int_equal(raw_read(b, &h, &p), 0);
  assert_int_equal(h.type, HFP_RESULT);
  free(p);
  close(b);
  hfc_close(c);
  assert_int_equal(server_stop(&d, 20000), 0);
}

/* Item: frames still queued when their connection goes are dropped unrun
 * (docs/SERVER.md, "Limits and backpressure"): nothing would read their
 * results, and their places and memory would be refused to other clients
 * until the worker had run them for no one. One connection's frame waits
 * in the batcher for a partner (--max-batch 2, a delay of 10 s); another
 * connection queues 4 frames of another size behind it and closes with a
 * STATS_REPLY unread, which resets the connection (a plain close looks
 * like a half-close, which is answered: PROTOCOL.md): STATS' queue_depth
 * falls from 5 to 1 at once, the log says so, and the first connection's
 * batch still runs and answers when its partner comes. */
static void test_gone_connection_frames_dropped(void **state) {
  (void)state;
  enum { W = 24 };
  server d;
  const char *args[] = {"--max-batch", "2", "--max-queue-delay-us", "10000000", NULL};
  hfc_client *c;
  assert_int_equal(server_start_connected(&H, &d, args, "stats", &c), 0);
  int fd[2];
  raw_clients(&d, fd, 2);
  send_small(fd[0], 1, W, W);
  expect_queue_depth(c, 1, "a frame in the batcher");
  uint8_t stats[HFP_HEADER_SIZE];
  hfp_header_encode(&(hfp_header){HFP_STATS, 0, 9, 0}, stats);
  assert_int_equal(raw_send(fd[1], stats, sizeof stats), 0);
  struct pollfd pf = {fd[1], POLLIN, 0};
  assert_int_equal(poll(&pf, 1, 5000), 1); /* the reply is there, left unread */
  for (uint32_t id = 1; id <= 4; id++) send_small(fd[1], id, W + 8, W);
  expect_queue_depth(c, 5, "4 frames of another size queued behind it");
  close(fd[1]);
  expect_queue_depth(c, 1, "their connection closed");
  for (int waited = 0; !server_log_has(&d, "4 queued frames dropped unrun"); waited += 10) {
    if (waited > 2000) {
      server_dump_log(&d);
      fail_msg("no log line for the 4 frames dropped");
    }
    usleep(10000);
  }
  send_small(fd[0], 2, W, W);
  int code = 0;
  hfp_result r;
  uint8_t *p;
  for (uint32_t id = 1; id <= 2; id++) {
    assert_int_equal(read_reply(fd[0], id, &code, &r, &p), HFP_RESULT);
    free(p);
    assert_int_equal(r.status, 0);
    assert_int_equal(r.batch, 2);
  }
  expect_queue_depth(c, 0, "every frame answered or dropped");
  close(fd[0]);
  hfc_close(c);
  assert_int_equal(server_stop(&d, 20000), 0);
}

/* read_any_reply, its payload freed (r's fixed fields stay). */
static int reply_status(int fd, uint32_t id, int *status, hfp_result *r) {
  uint8_t *p = NULL;
  int type = read_any_reply(fd, id, status, r, &p);
  free(p);
  return type;
}

/* Item: a connection under its share is not refused for a queue that
 * connections over theirs keep full (docs/SERVER.md, "Limits and
 * backpressure"): the newest queued frame of the connection holding the
 * most leaves the queue, answered by a RESULT of status BUSY (it was
 * admitted), and the newcomer's frame takes its place. While one large
 * frame runs: connection A, alone, holds it and 3 queued frames (its
 * fifth is refused, its share being every place but the running one's);
 * B's first frame takes the fourth place and its second (share 2 with two
 * connections holding frames) pushes out A's newest; C's frame (share 1)
 * pushes out A's next newest, A still holding the most. The connections
 * are one process's: shares by connection. */
static void test_queue_push_out(void **state) {
  (void)state;
  enum { BIG = 384, W = 16 };
  server d;
  const char *args[] = {"--queue-size", "4", "--max-inflight", "8", "--max-batch", "1",
                        "--queue-share-by", "connection", NULL};
  hfc_client *c;
  assert_int_equal(server_start_connected(&H, &d, args, "stats", &c), 0);
  int fd[3], st;
  hfp_result r;
  raw_clients(&d, fd, 3);
  send_small(fd[0], 1, BIG, BIG);
  for (uint32_t id = 2; id <= 5; id++) send_small(fd[0], id, W, W);
  /* A's share, and the message names the option that sets it */
  hfp_header h;
  uint8_t *p = NULL;
  hfp_error e;
  assert_int_equal(raw_read(fd[0], &h, &p), 0);
  assert_int_equal(h.type, HFP_ERROR);
  assert_int_equal(h.request_id, 5);
  assert_int_equal(hfp_decode_error(p, h.length, &e), 0);
  free(p);
  assert_int_equal(e.code, HFP_E_BUSY);
  if (!strstr(e.message, "holds its share of the queue (4 frame(s) of --queue-size 4") ||
      !strstr(e.message, "can raise --queue-size"))
    fail_msg("BUSY for A's share says: %s", e.message);
  double t0 = now_ms();                                   /* the large frame admitted */
  expect_queue_depth(c, 3, "A's large frame running and 3 queued");
  send_small(fd[1], 1, W, W);
  send_small(fd[1], 2, W, W);
  assert_int_equal(reply_status(fd[0], 4, &st, &r), HFP_RESULT);
  assert_int_equal(st, HFP_E_BUSY);                       /* pushed out by B's second */
  expect_queue_depth(c, 4, "B's two frames in the queue");
  send_small(fd[2], 1, W, W);
  assert_int_equal(reply_status(fd[0], 3, &st, &r), HFP_RESULT);
  assert_int_equal(st, HFP_E_BUSY);                       /* pushed out by C's */
  double pushed_ms = now_ms() - t0;
  assert_int_equal(reply_status(fd[0], 1, &st, &r), HFP_RESULT);
  assert_int_equal(st, 0);
  printf("the %dx%d frame ran %.0f ms (queued %.0f ms); both push-outs within %.0f ms of "
         "its admission\n", BIG, BIG, r.timing.infer_us / 1e3, r.timing.queue_us / 1e3,
         pushed_ms);
  assert_int_equal(reply_status(fd[0], 2, &st, &r), HFP_RESULT);
  assert_int_equal(st, 0);
  for (uint32_t id = 1; id <= 2; id++) {
    assert_int_equal(reply_status(fd[1], id, &st, &r), HFP_RESULT);
    assert_int_equal(st, 0);
  }
  assert_int_equal(reply_status(fd[2], 1, &st, &r), HFP_RESULT);
  assert_int_equal(st, 0);
  expect_queue_depth(c, 0, "every frame answered");
  for (int k = 0; k < 3; k++) close(fd[k]);
  hfc_close(c);
  assert_int_equal(server_stop(&d, 20000), 0);
}

int main(void) {
  const struct CMUnitTest tests[] = {
    cmocka_unit_test(test_batches_form_within_budget),
    cmocka_unit_test(test_default_size_is_landscape),
    cmocka_unit_test(test_announced_maximum_is_admitted),
    cmocka_unit_test(test_announced_maximum_after_other_plans),
    cmocka_unit_test(test_queue_share_within_window),
    cmocka_unit_test(test_queue_shared),
    cmocka_unit_test(test_queue_push_out),
    cmocka_unit_test(test_batcher_frames_are_queued),
    cmocka_unit_test(test_gone_connection_frames_dropped),
    cmocka_unit_test(test_expired_frame_gives_back_memory),
    cmocka_unit_test(test_unrun_frame_gives_back_buffers),
    cmocka_unit_test(test_segment_too_large_vs_busy),
    cmocka_unit_test(test_memory_charged_as_received),
    cmocka_unit_test(test_slow_senders_hold_what_they_sent),
    cmocka_unit_test(test_inference_memory_in_budget),
    cmocka_unit_test(test_mixed_load_within_budget),
  };
  if (getenv("HF_TEST_FILTER")) cmocka_set_test_filter(getenv("HF_TEST_FILTER"));
  return cmocka_run_group_tests(tests, setup, teardown);
}
