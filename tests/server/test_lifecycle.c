/* hairfilterd's start and stop (docs/SERVER.md, "Options", "Shutdown"):
 * bad --listen URLs and tokens are refused at start with a message naming
 * them (exit status 2), the ready file is never written through a planted
 * symlink, and SIGTERM finishes in bounded time even when a client leaves
 * its replies unread; a second signal shortens the wait instead of killing
 * the daemon, and no exit path leaves the socket or the ready file. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <errno.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#include "harness.h"

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

/* Waits up to timeout_ms for the daemon to exit; its status, or -1. */
static int wait_exit(server *s, int timeout_ms) {
  for (int waited = 0; waited < timeout_ms; waited += 10) {
    int st;
    if (waitpid(s->pid, &st, WNOHANG) == s->pid) {
      s->pid = 0;
      return WIFEXITED(st) ? WEXITSTATUS(st) : 128 + WTERMSIG(st);
    }
    usleep(10000);
  }
  return -1;
}

/* Item: --listen URLs go through the one parser; a bad port is exit status
 * 2 with a message that names the URL. Both option forms work. */
static void test_bad_listen_urls(void **state) {
  (void)state;
  static const struct {
    const char *url, *says;
  } bad[] = {
    {"tcp:127.0.0.1:70000", "port 70000 is outside 0..65535"},
    {"tcp:127.0.0.1:65536", "port 65536 is outside 0..65535"},
    {"tcp:127.0.0.1:80x", "port '80x' is not a decimal number"},
    {"tcp:127.0.0.1:-5", "port '-5' is not a decimal number"},
    {"tcp:::1:80", "brackets"},
    {"unix:", "empty socket path"},
    {"http://127.0.0.1:80", "want unix:PATH"},
  };
  char out[4096];
  for (size_t k = 0; k < sizeof bad / sizeof bad[0]; k++) {
    const char *args[] = {"--listen", bad[k].url, "--weights-dir", H.weights_dir, "--no-auth",
                          NULL};
    int st = daemon_run(args, NULL, 10000, out, sizeof out);
    if (st != 2 || !strstr(out, bad[k].says) || !strstr(out, bad[k].url))
      fail_msg("--listen %s: status %d, said: %s", bad[k].url, st, out);
  }
  /* A socket in a directory that is not there: said as that, not as a
   * permission problem. */
  const char *nodir[] = {"--listen", "unix:/nonexistent-hairfilter-dir/s.sock", "--weights-dir",
                         H.weights_dir, NULL};
  int st = daemon_run(nodir, NULL, 10000, out, sizeof out);
  if (st == 0 || !strstr(out, "the directory /nonexistent-hairfilter-dir does not exist") ||
      strstr(out, "permission denied"))
    fail_msg("--listen in a missing directory: status %d, said: %s", st, out);
  /* --opt=value (as in deploy/kubernetes) and a token from the
   * environment; the ready file lists the resolved URL */
  server d;
  char listen[300];
  snprintf(listen, sizeof listen, "--listen=unix:%s/eq.sock", H.dir);
  const char *args[] = {listen, "--max-batch=2", NULL};
  assert_int_equal(server_start(&H, &d, args), 0);
  hfc_client *c = NULL;
  char url[300];
  snprintf(url, sizeof url, "unix:%s/eq.sock", H.dir);
  assert_int_equal(hfc_connect(url, NULL, &c), 0);
  assert_int_equal(hfc_info(c)->max_batch, 2);
  hfc_close(c);
  assert_int_equal(server_stop(&d, 20000), 0);
}

/* Item: without --max-batch, a CPU backend runs frames one at a time
 * (HELLO_OK says max_batch 1), unless --warm asks for larger batches. */
static void test_default_max_batch(void **state) {
  (void)state;
  static const struct {
    const char *warm;
    int want;
  } cases[] = {{NULL, 1}, {"32x32x3,32x32", 3}};
  for (size_t k = 0; k < sizeof cases / sizeof cases[0]; k++) {
    server d;
    char listen[300], url[300];
    snprintf(listen, sizeof listen, "--listen=unix:%s/mb.sock", H.dir);
    snprintf(url, sizeof url, "unix:%s/mb.sock", H.dir);
    const char *args[] = {listen, cases[k].warm ? "--warm" : NULL, cases[k].warm, NULL};
    assert_int_equal(server_start(&H, &d, args), 0);
    hfc_client *c = NULL;
    assert_int_equal(hfc_connect(url, NULL, &c), 0);
    if (hfc_info(c)->max_batch != cases[k].want)
      fail_msg("--warm %s: max_batch %d, not %d", cases[k].warm ? cases[k].warm : "(none)",
               hfc_info(c)->max_batch, cases[k].want);
    hfc_close(c);
    assert_int_equal(server_stop(&d, 20000), 0);
  }
}

/* Item: a token from $HAIRFILTERD_TOKEN follows the rules of one from a
 * file: same refusals, same messages; a trailing newline (a Kubernetes
 * secret's) is dropped in both. */
static void test_token_rules(void **state) {
  (void)state;
  static const struct {
    const char *token, *says;
  } bad[] = {
    {"has space", "must be printable ASCII without spaces"},
    {"tab\there", "must be printable ASCII without spaces"},
    {"caf\xc3\xa9", "must be printable ASCII without spaces"},
    {"", "must be 1..256 bytes"},
    {"\n", "must be 1..256 bytes"},
  };
  char out[4096], file[300];
  snprintf(file, sizeof file, "%s/token", H.dir);
  for (size_t k = 0; k < sizeof bad / sizeof bad[0]; k++) {
    const char *env_args[] = {"--listen", "tcp:127.0.0.1:0", "--weights-dir", H.weights_dir,
                              NULL};
    int st = daemon_run(env_args, bad[k].token, 10000, out, sizeof out);
    if (st != 2 || !strstr(out, "token in $HAIRFILTERD_TOKEN ") || !strstr(out, bad[k].says))
      fail_msg("$HAIRFILTERD_TOKEN '%s': status %d, said: %s", bad[k].token, st, out);
    FILE *f = fopen(file, "w");
    assert_non_null(f);
    fputs(bad[k].token, f);
    fclose(f);
    const char *file_args[] = {"--listen", "tcp:127.0.0.1:0", "--weights-dir", H.weights_dir,
                               "--auth-token-file", file, NULL};
    st = daemon_run(file_args, NULL, 10000, out, sizeof out);
    if (st != 2 || !strstr(out, file) || !strstr(out, bad[k].says))
      fail_msg("token file '%s': status %d, said: %s", bad[k].token, st, out);
  }
  char longtok[300];
  memset(longtok, 'k', 257);
  longtok[257] = 0;
  const char *env_args[] = {"--listen", "tcp:127.0.0.1:0", "--weights-dir", H.weights_dir,
                            NULL};
  assert_int_equal(daemon_run(env_args, longtok, 10000, out, sizeof out), 2);
  assert_non_null(strstr(out, "must be 1..256 bytes"));
  /* a trailing newline is not part of the token */
  server d;
  assert_int_equal(server_start_ex(&H, &d, NULL, NULL, TEST_TOKEN "\n"), 0);
  hfc_client *c = NULL;
  hfc_options o = test_options("token", TEST_TOKEN, 20000);
  assert_int_equal(hfc_connect(d.tcp_url, &o, &c), 0);
  hfc_close(c);
  assert_int_equal(server_stop(&d, 20000), 0);
}

static void write_file(const char *path, const char *text) {
  FILE *f = fopen(path, "w");
  assert_non_null(f);
  fputs(text, f);
  fclose(f);
}

static void assert_file_is(const char *path, const char *text) {
  char buf[256] = "";
  FILE *f = fopen(path, "r");
  assert_non_null(f);
  size_t n = fread(buf, 1, sizeof buf - 1, f);
  fclose(f);
  buf[n] = 0;
  assert_string_equal(buf, text);
}

/* Item: --ready-file never writes through a symlink, neither one planted
 * at the old temporary name nor one at the ready file's own path. */
static void test_ready_file_symlinks(void **state) {
  (void)state;
  char ready[300], tmp[320], victim1[300], victim2[300];
  snprintf(ready, sizeof ready, "%s/planted-ready", H.dir);
  snprintf(tmp, sizeof tmp, "%s.tmp", ready);
  snprintf(victim1, sizeof victim1, "%s/victim1", H.dir);
  snprintf(victim2, sizeof victim2, "%s/victim2", H.dir);
  write_file(victim1, "precious 1\n");
  write_file(victim2, "precious 2\n");
  assert_int_equal(symlink(victim1, tmp), 0);
  assert_int_equal(symlink(victim2, ready), 0);
  server d;
  assert_int_equal(server_start_ex(&H, &d, NULL, ready, NULL), 0);
  assert_file_is(victim1, "precious 1\n");
  assert_file_is(victim2, "precious 2\n");
  struct stat st;
  assert_int_equal(lstat(ready, &st), 0);
  assert_true(S_ISREG(st.st_mode));
  assert_true(d.unix_url[0] && d.tcp_url[0]);
  assert_int_equal(server_stop(&d, 20000), 0);
  /* removed on exit; the planted link at the old name is left alone */
  assert_int_equal(access(ready, F_OK), -1);
  assert_int_equal(lstat(tmp, &st), 0);
  assert_file_is(victim1, "precious 1\n");
  unlink(tmp);
}

/* A client on url (tcp: with the token) that sends frames with large
 * results and reads none of them. */
static int hog_at(const char *url, int n) {
  int fd = raw_connect(url);
  assert_true(fd >= 0);
  assert_int_equal(raw_hello(fd, strncmp(url, "tcp:", 4) ? NULL : TEST_TOKEN), 0);
  float *in = make_features(160, 120, 2, 1);
  size_t len;
  uint8_t *f = raw_filter(1, "Tiny", 160, 120, 2, in, &len);
  for (int i = 0; i < n; i++) {
    hfp_put_u32(f + 8, (uint32_t)i + 1);
    assert_int_equal(raw_send(fd, f, len), 0);
  }
  free(f);
  free(in);
  return fd;
}

static int hog(const server *d, int n) { return hog_at(d->unix_url, n); }

/* Item: SIGTERM while a client leaves 230 KiB replies unread: the daemon
 * answers what it admitted, waits --flush-timeout-ms for the reader, then
 * closes and exits 0 with its socket and ready file gone. */
static void test_sigterm_with_unread_replies(void **state) {
  (void)state;
  server d;
  const char *args[] = {"--flush-timeout-ms", "500", "--drain-timeout-ms", "5000",
                        "--max-batch", "1", NULL};
  assert_int_equal(server_start(&H, &d, args), 0);
  int fd = hog(&d, 12);
  usleep(500000);   /* admitted and computed; the replies sit unread */
  double t0 = now_ms();
  kill(d.pid, SIGTERM);
  int st = wait_exit(&d, 15000);
  double took = now_ms() - t0;
  if (st != 0) server_dump_log(&d);
  assert_int_equal(st, 0);
  printf("SIGTERM to exit with unread replies: %.0f ms (flush timeout 500 ms)\n", took);
  assert_true(took >= 400 && took < 5000);
  assert_true(server_log_has(&d, "flush timeout: closing 1 connection"));
  /* The peer is there, not reading: the stop line does not say it left. */
  assert_true(server_log_has(&d, "answer(s) not delivered (peer gone or not reading)"));
  assert_int_equal(access(d.ready, F_OK), -1);
  assert_int_equal(access(d.unix_url + 5, F_OK), -1);
  close(fd);
}

/* Item: SIGTERM while a client is in the middle of sending a frame larger
 * than the socket holds, with replies waiting that it reads only once the
 * frame is out (libhairfilter's order): the stopping server drops what the
 * client still sends instead of no longer reading it, so the send
 * completes, every admitted frame's reply arrives, and the stop takes no
 * flush timeout. With reading stopped the two waited on each other until
 * the flush timeout closed the connection with the replies unsent. */
static void test_sigterm_while_a_frame_is_half_sent(void **state) {
  (void)state;
  for (int tcp = 0; tcp < 2; tcp++) {
    server d;
    const char *args[] = {"--flush-timeout-ms", "6000", "--max-batch", "1", NULL};
    assert_int_equal(server_start(&H, &d, args), 0);
    int fd = hog_at(tcp ? d.tcp_url : d.unix_url, 4);
    usleep(500000);   /* the 4 frames admitted and computed; 920 KiB of replies unread */
    /* Far more than the socket holds (loopback TCP grows its buffers to
     * several MiB): 12 MiB, 48 over TCP. */
    int side = tcp ? 1024 : 512;
    float *in = make_features(side, side, 2, 2);
    size_t len, part = (size_t)1 << 20;
    uint8_t *f = raw_filter(100, "Tiny", side, side, 2, in, &len);
    assert_true(len > 8 * part);
    assert_int_equal(raw_send(fd, f, part), 0);   /* the head and the first MiB */
    usleep(200000);
    double t0 = now_ms();
    kill(d.pid, SIGTERM);
    usleep(300000);   /* stopped: every admitted frame was answered */
    /* The rest: only a server that reads lets it out (the raw socket's
     * send gives up after 10 s, the server's flush after 6). */
    int sent = raw_send(fd, f + part, len - part);
    int results = 0;
    hfp_header h;
    uint8_t *p;
    while (raw_read(fd, &h, &p) == 0) {
      results += h.type == HFP_RESULT;
      free(p);
    }
    close(fd);   /* at the server's end of stream, as libhairfilter does */
    int st = wait_exit(&d, 15000);
    double took = now_ms() - t0;
    printf("SIGTERM mid-frame over %s: send %s, %d of 4 replies, exit in %.0f ms (flush timeout "
           "6000)\n", tcp ? "TCP" : "a Unix socket", sent ? "failed" : "completed", results, took);
    if (st != 0) server_dump_log(&d);
    assert_int_equal(st, 0);
    assert_int_equal(sent, 0);
    assert_int_equal(results, 4);
    assert_false(server_log_has(&d, "flush timeout"));
    assert_true(took < 4000);
    free(f);
    free(in);
  }
}

/* Item: a second SIGTERM or SIGINT while replies wait to be read closes
 * what is left at once; the daemon exits 0, not by the signal's default
 * action, and removes its files. */
static void test_second_signal_shortens_the_wait(void **state) {
  (void)state;
  int sigs[2] = {SIGTERM, SIGINT};
  for (int k = 0; k < 2; k++) {
    server d;
    const char *args[] = {"--flush-timeout-ms", "60000", "--max-batch", "1", NULL};
    assert_int_equal(server_start(&H, &d, args), 0);
    int fd = hog(&d, 12);
    usleep(500000);
    kill(d.pid, SIGTERM);
    usleep(300000);
    /* still flushing: the first signal alone would wait a minute */
    assert_true(server_alive(&d));
    assert_int_equal(access(d.ready, F_OK), -1);
    assert_int_equal(access(d.unix_url + 5, F_OK), -1);
    double t0 = now_ms();
    kill(d.pid, sigs[k]);
    int st = wait_exit(&d, 10000);
    if (st != 0) server_dump_log(&d);
    assert_int_equal(st, 0);
    assert_true(now_ms() - t0 < 3000);
    assert_true(server_log_has(&d, "second "));
    assert_true(server_log_has(&d, "stopped: "));
    close(fd);
  }
}

/* Item: a failed start removes what it made: a Unix socket bound before
 * a later listener failed. */
static void test_failed_start_leaves_nothing(void **state) {
  (void)state;
  char sock[300], listen[320], out[4096];
  snprintf(sock, sizeof sock, "%s/failed.sock", H.dir);
  snprintf(listen, sizeof listen, "unix:%s", sock);
  const char *args[] = {"--listen", listen, "--listen", "tcp:256.1.1.1:7070", "--no-auth",
                        "--weights-dir", H.weights_dir, "--backend", "cpu-ref", NULL};
  int st = daemon_run(args, NULL, 20000, out, sizeof out);
  if (st != 1) fail_msg("status %d: %s", st, out);
  assert_non_null(strstr(out, "tcp:256.1.1.1:7070"));
  assert_int_equal(access(sock, F_OK), -1);
}

/* One file under two variant names is refused at start, by path and by
 * a hard link to it (the same file under another path), with a message
 * naming both entries; two copies of it are two variants. */
static void test_one_file_two_names(void **state) {
  (void)state;
  char sock[300], listen[320], small[300], link_path[300], copy[300], a[340], b[340], out[4096];
  snprintf(sock, sizeof sock, "%s/twice.sock", H.dir);
  snprintf(listen, sizeof listen, "unix:%s", sock);
  snprintf(small, sizeof small, "%s/Small.safetensors", H.weights_dir);
  snprintf(link_path, sizeof link_path, "%s/small-link.safetensors", H.dir);
  snprintf(copy, sizeof copy, "%s/small-copy.safetensors", H.dir);
  unlink(link_path);
  assert_int_equal(link(small, link_path), 0);
  const char *seconds[] = {small, link_path};
  for (int k = 0; k < 2; k++) {
    snprintf(a, sizeof a, "A=%s", small);
    snprintf(b, sizeof b, "B=%s", seconds[k]);
    const char *args[] = {"--listen", listen, "--no-auth", "--weights", a, "--weights", b,
                          "--backend", "cpu-ref", NULL};
    int st = daemon_run(args, NULL, 20000, out, sizeof out);
    if (st == 0 || !strstr(out, "are the same file") || !strstr(out, a) || !strstr(out, b))
      fail_msg("--weights %s --weights %s: status %d: %s", a, b, st, out);
  }
  /* A copy is another file: both names are served. */
  char cmd[700];
  snprintf(cmd, sizeof cmd, "cp '%s' '%s'", small, copy);
  assert_int_equal(system(cmd), 0);
  snprintf(b, sizeof b, "B=%s", copy);
  const char *args[] = {"--weights", a, "--weights", b, NULL};
  server d;
  assert_int_equal(server_start(&H, &d, args), 0);
  hfc_client *c = NULL;
  assert_int_equal(hfc_connect(d.unix_url, NULL, &c), 0);
  hfc_stats st;
  assert_int_equal(hfc_get_stats(c, &st), 0);
  int served = 0;
  for (int i = 0; i < st.num_variants; i++)
    served += !strcmp(st.variants[i].name, "A") || !strcmp(st.variants[i].name, "B");
  hfc_close(c);
  assert_int_equal(server_stop(&d, 10000), 0);
  assert_int_equal(served, 2);
  unlink(link_path);
  unlink(copy);
}

int main(void) {
  const struct CMUnitTest tests[] = {
    cmocka_unit_test(test_bad_listen_urls),
    cmocka_unit_test(test_default_max_batch),
    cmocka_unit_test(test_token_rules),
    cmocka_unit_test(test_ready_file_symlinks),
    cmocka_unit_test(test_sigterm_with_unread_replies),
    cmocka_unit_test(test_sigterm_while_a_frame_is_half_sent),
    cmocka_unit_test(test_second_signal_shortens_the_wait),
    cmocka_unit_test(test_failed_start_leaves_nothing),
    cmocka_unit_test(test_one_file_two_names),
  };
  return cmocka_run_group_tests(tests, setup, teardown);
}
