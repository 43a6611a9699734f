/* make_test_certs DIR: the TLS tests' certificates (test_certs.h) into DIR,
 * for the tests that are not C (the Python client's). */
#include <stdio.h>

#include "test_certs.h"

int main(int argc, char **argv) {
  if (argc != 2) {
    fprintf(stderr, "usage: make_test_certs DIR\n");
    return 2;
  }
  return test_certs_make(argv[1]) ? 1 : 0;
}
