/* Certificates for the TLS tests, generated with the OpenSSL API. */
#ifndef HF_TEST_CERTS_H
#define HF_TEST_CERTS_H

/* Writes into dir, each as STEM.pem (certificate) and STEM.key (its EC
 * P-256 key, PEM):
 *   ca            a CA, valid from yesterday for 30 days
 *   other-ca      another CA, which signed nothing the servers use
 *   server        signed by ca, subjectAltName DNS:localhost only
 *   expired       the same, but valid for one day, 31 days ago
 *   client        a client certificate (clientAuth) signed by ca
 *   client-other  a client certificate signed by other-ca
 * Returns 0, or -1 after printing OpenSSL's errors. */
int test_certs_make(const char *dir);

#endif
