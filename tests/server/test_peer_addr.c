/*
 * server/peer_addr.c, the pure functions of an address: which client a
 * peer is (hfd_peer_client_name) and whether an address is loopback. The
 * peers no test host can connect from (many addresses of one IPv6 /64,
 * another link's link-local address) are made here as the kernel would
 * give them.
 */
#include <arpa/inet.h>
#include <netinet/in.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <string.h>

#include <cmocka.h>

#include "peer_addr.h"

/* A peer's address as getpeername gives it: IPv6 when text has a colon. */
static struct sockaddr_storage peer(const char *text, unsigned scope) {
  struct sockaddr_storage ss;
  memset(&ss, 0, sizeof ss);
  if (strchr(text, ':')) {
    struct sockaddr_in6 *s6 = (struct sockaddr_in6 *)&ss;
    s6->sin6_family = AF_INET6;
    s6->sin6_port = htons(40000);
    s6->sin6_scope_id = scope;
    assert_int_equal(inet_pton(AF_INET6, text, &s6->sin6_addr), 1);
  } else {
    struct sockaddr_in *s4 = (struct sockaddr_in *)&ss;
    s4->sin_family = AF_INET;
    s4->sin_port = htons(40000);
    assert_int_equal(inet_pton(AF_INET, text, &s4->sin_addr), 1);
  }
  return ss;
}

/* The client name of the peer at text (scope id scope), IPv6 peers
 * counted by their first bits (--ipv6-client-prefix). */
static const char *name_by(const char *text, unsigned scope, int bits) {
  static char buf[64];  /* hfd_client.name */
  struct sockaddr_storage ss = peer(text, scope);
  assert_int_equal(hfd_peer_client_name((const struct sockaddr *)&ss, bits, buf, sizeof buf), 0);
  return buf;
}

/* The same with the default prefix, /64. */
static const char *name_of(const char *text, unsigned scope) {
  return name_by(text, scope, HFD_V6_CLIENT_PREFIX_DEFAULT);
}

static void test_ipv4_and_v4_mapped_are_one(void **state) {
  (void)state;
  assert_string_equal(name_of("192.0.2.7", 0), "address 192.0.2.7");
  /* An IPv6 listener that takes IPv4 sees the same peer v4-mapped. */
  assert_string_equal(name_of("::ffff:192.0.2.7", 0), "address 192.0.2.7");
  assert_string_not_equal(name_of("192.0.2.8", 0), "address 192.0.2.7");
}

static void test_ipv6_loopback_is_itself(void **state) {
  (void)state;
  assert_string_equal(name_of("::1", 0), "address ::1");
  assert_string_equal(name_by("::1", 0, 48), "address ::1");
}

static void test_ipv6_per_prefix(void **state) {
  (void)state;
  char a[64], b[64];
  /* Two addresses of one /64: one host's, one client. */
  strcpy(a, name_of("2001:db8:1:2::1", 0));
  strcpy(b, name_of("2001:db8:1:2:a1b2:c3d4:e5f6:789", 0));
  assert_string_equal(a, "address 2001:db8:1:2::/64");
  assert_string_equal(a, b);
  /* Another /64 of the same /48: another client. */
  assert_string_equal(name_of("2001:db8:1:3::1", 0), "address 2001:db8:1:3::/64");
  /* --ipv6-client-prefix 56 joins them, 128 counts each address, and a
   * length that is not a multiple of 8 keeps only its leading bits. */
  assert_string_equal(name_by("2001:db8:1:3::1", 0, 56), "address 2001:db8:1::/56");
  assert_string_equal(name_by("2001:db8:1:2::1", 0, 56), "address 2001:db8:1::/56");
  assert_string_equal(name_by("2001:db8:1:2::1", 0, 128), "address 2001:db8:1:2::1");
  assert_string_equal(name_by("2001:db8:1:ffff::1", 0, 60), "address 2001:db8:1:fff0::/60");
  assert_string_equal(name_by("2001:db8:1:ffff::1", 0, 127), "address 2001:db8:1:ffff::/127");
  /* The longest name fits hfd_client.name. */
  assert_string_equal(name_by("fe80:ffff:ffff:ffff:ffff:ffff:ffff:ffff", 4294967295u, 127),
                      "address fe80:ffff:ffff:ffff:ffff:ffff:ffff:fffe%4294967295/127");
  /* A prefix outside 48..128 is refused, not taken for another. */
  char buf[64];
  struct sockaddr_storage ss = peer("2001:db8::1", 0);
  assert_int_equal(hfd_peer_client_name((const struct sockaddr *)&ss, 47, buf, sizeof buf), -1);
  assert_int_equal(hfd_peer_client_name((const struct sockaddr *)&ss, 129, buf, sizeof buf), -1);
  /* An IPv4 peer is its address whatever the prefix. */
  assert_string_equal(name_by("::ffff:192.0.2.7", 0, 48), "address 192.0.2.7");
}

static void test_link_local_per_interface(void **state) {
  (void)state;
  char a[64], b[64];
  strcpy(a, name_of("fe80::1", 2));
  strcpy(b, name_of("fe80::1", 3));
  /* One address on two links: two hosts, two clients. */
  assert_string_equal(a, "address fe80::%2/64");
  assert_string_equal(b, "address fe80::%3/64");
  assert_string_not_equal(a, b);
  /* Two addresses on one link: one /64 there. */
  assert_string_equal(name_of("fe80::aa:bbff:fecc:dd01", 2), a);
  assert_string_equal(name_by("fe80::1", 2, 128), "address fe80::1%2");
  /* A global address has no interface in its name. */
  assert_string_equal(name_of("2001:db8::1", 5), "address 2001:db8::/64");
}

static void test_name_that_does_not_fit(void **state) {
  (void)state;
  char small[12];
  struct sockaddr_storage ss = peer("2001:db8:1:2::1", 0);
  assert_int_equal(hfd_peer_client_name((const struct sockaddr *)&ss, 64, small, sizeof small), -1);
  assert_string_equal(small, "");
  struct sockaddr other;
  memset(&other, 0, sizeof other);
  other.sa_family = AF_UNIX;
  assert_int_equal(hfd_peer_client_name(&other, 64, small, sizeof small), -1);
}

static void test_loopback(void **state) {
  (void)state;
  assert_int_equal(hfd_host_is_loopback("127.0.0.1"), 1);
  assert_int_equal(hfd_host_is_loopback("127.3.2.1"), 1);
  assert_int_equal(hfd_host_is_loopback("::1"), 1);
  assert_int_equal(hfd_host_is_loopback("::ffff:127.0.0.1"), 1);
  assert_int_equal(hfd_host_is_loopback("::ffff:127.9.0.1"), 1);
  assert_int_equal(hfd_host_is_loopback("localhost"), 1);
  assert_int_equal(hfd_host_is_loopback("::ffff:10.0.0.1"), 0);
  assert_int_equal(hfd_host_is_loopback("10.0.0.1"), 0);
  assert_int_equal(hfd_host_is_loopback("::"), 0);
  assert_int_equal(hfd_host_is_loopback("0.0.0.0"), 0);
  assert_int_equal(hfd_host_is_loopback("::127.0.0.1"), 0);  /* not v4-mapped */
  assert_int_equal(hfd_host_is_loopback("example.org"), -1);
  struct sockaddr_storage ss = peer("::ffff:127.0.0.1", 0);
  assert_int_equal(hfd_addr_is_loopback((const struct sockaddr *)&ss), 1);
}

int main(void) {
  const struct CMUnitTest tests[] = {
    cmocka_unit_test(test_ipv4_and_v4_mapped_are_one),
    cmocka_unit_test(test_ipv6_loopback_is_itself),
    cmocka_unit_test(test_ipv6_per_prefix),
    cmocka_unit_test(test_link_local_per_interface),
    cmocka_unit_test(test_name_that_does_not_fit),
    cmocka_unit_test(test_loopback),
  };
  return cmocka_run_group_tests(tests, NULL, NULL);
}
