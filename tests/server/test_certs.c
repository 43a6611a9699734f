/* Certificates for the TLS tests, made with the OpenSSL API (EC P-256 keys,
 * SHA-256 signatures): the same files a render farm makes with the openssl
 * commands of docs/SERVER.md ("TLS"), plus the broken ones the tests need. */
#define _POSIX_C_SOURCE 200809L
#include "test_certs.h"

#include <stdio.h>
#include <string.h>

#include <openssl/ec.h>
#include <openssl/err.h>
#include <openssl/evp.h>
#include <openssl/pem.h>
#include <openssl/x509.h>
#include <openssl/x509v3.h>

static int add_ext(X509 *x, X509 *issuer, int nid, const char *value) {
  X509V3_CTX ctx;
  X509V3_set_ctx_nodb(&ctx);
  X509V3_set_ctx(&ctx, issuer, x, NULL, NULL, 0);
  X509_EXTENSION *e = X509V3_EXT_conf_nid(NULL, &ctx, nid, value);
  if (!e) return -1;
  int ok = X509_add_ext(x, e, -1);
  X509_EXTENSION_free(e);
  return ok == 1 ? 0 : -1;
}

/* A certificate for key named cn, valid from days_from to days_to (days
 * from now, negative in the past), signed by issuer/issuer_key (NULL: self).
 * san: subjectAltName ("DNS:localhost"), or NULL for a CA or a client. */
static X509 *make_cert(EVP_PKEY *key, const char *cn, long days_from, long days_to, X509 *issuer,
                       EVP_PKEY *issuer_key, const char *san, int is_ca, int serial) {
  X509 *x = X509_new();
  if (!x) return NULL;
  X509_set_version(x, 2);
  ASN1_INTEGER_set(X509_get_serialNumber(x), serial);
  X509_gmtime_adj(X509_getm_notBefore(x), days_from * 86400L);
  X509_gmtime_adj(X509_getm_notAfter(x), days_to * 86400L);
  X509_set_pubkey(x, key);
  X509_NAME *name = X509_get_subject_name(x);
  X509_NAME_add_entry_by_txt(name, "O", MBSTRING_ASC, (const unsigned char *)"hairfilter tests",
                             -1, -1, 0);
  X509_NAME_add_entry_by_txt(name, "CN", MBSTRING_ASC, (const unsigned char *)cn, -1, -1, 0);
  X509 *iss = issuer ? issuer : x;
  X509_set_issuer_name(x, X509_get_subject_name(iss));
  int bad = 0;
  if (is_ca) {
    bad |= add_ext(x, iss, NID_basic_constraints, "critical,CA:TRUE");
    bad |= add_ext(x, iss, NID_key_usage, "critical,keyCertSign,cRLSign");
  } else {
    bad |= add_ext(x, iss, NID_basic_constraints, "critical,CA:FALSE");
    bad |= add_ext(x, iss, NID_key_usage, "critical,digitalSignature");
    bad |= add_ext(x, iss, NID_ext_key_usage, san ? "serverAuth" : "clientAuth");
  }
  bad |= add_ext(x, iss, NID_subject_key_identifier, "hash");
  if (issuer) bad |= add_ext(x, iss, NID_authority_key_identifier, "keyid");
  if (san) bad |= add_ext(x, iss, NID_subject_alt_name, san);
  if (bad || !X509_sign(x, issuer_key ? issuer_key : key, EVP_sha256())) {
    X509_free(x);
    return NULL;
  }
  return x;
}

static int write_pair(const char *dir, const char *stem, X509 *x, EVP_PKEY *k) {
  char path[512];
  snprintf(path, sizeof path, "%s/%s.pem", dir, stem);
  FILE *f = fopen(path, "w");
  if (!f || PEM_write_X509(f, x) != 1) {
    if (f) fclose(f);
    return -1;
  }
  fclose(f);
  snprintf(path, sizeof path, "%s/%s.key", dir, stem);
  f = fopen(path, "w");
  if (!f || PEM_write_PrivateKey(f, k, NULL, NULL, 0, NULL, NULL) != 1) {
    if (f) fclose(f);
    return -1;
  }
  fclose(f);
  return 0;
}

int test_certs_make(const char *dir) {
  enum { CA, OTHER_CA, SERVER, EXPIRED, CLIENT, CLIENT_OTHER, N };
  static const char *const stem[N] = {"ca", "other-ca", "server", "expired", "client",
                                      "client-other"};
  EVP_PKEY *k[N] = {0};
  X509 *x[N] = {0};
  int rc = -1;
  for (int i = 0; i < N; i++)
    if (!(k[i] = EVP_EC_gen("P-256"))) goto out;
  x[CA] = make_cert(k[CA], "hairfilter test CA", -1, 30, NULL, NULL, NULL, 1, 1);
  x[OTHER_CA] = make_cert(k[OTHER_CA], "another CA", -1, 30, NULL, NULL, NULL, 1, 2);
  if (!x[CA] || !x[OTHER_CA]) goto out;
  const char *san = "DNS:localhost";
  x[SERVER] = make_cert(k[SERVER], "localhost", -1, 30, x[CA], k[CA], san, 0, 3);
  /* Valid for a day, thirty days ago. */
  x[EXPIRED] = make_cert(k[EXPIRED], "localhost", -31, -30, x[CA], k[CA], san, 0, 4);
  x[CLIENT] = make_cert(k[CLIENT], "render-node-01", -1, 30, x[CA], k[CA], NULL, 0, 5);
  x[CLIENT_OTHER] =
      make_cert(k[CLIENT_OTHER], "render-node-02", -1, 30, x[OTHER_CA], k[OTHER_CA], NULL, 0, 6);
  for (int i = 0; i < N; i++)
    if (!x[i] || write_pair(dir, stem[i], x[i], k[i])) goto out;
  rc = 0;
out:
  if (rc) ERR_print_errors_fp(stderr);
  for (int i = 0; i < N; i++) {
    X509_free(x[i]);
    EVP_PKEY_free(k[i]);
  }
  return rc;
}
