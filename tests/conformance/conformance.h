/*
 * hfconformance: protocol/PROTOCOL.md checked rule by rule.
 *
 * Two suites share this library. The server suite connects to any server
 * that claims to speak the protocol (hairfilterd, a proxy, another
 * implementation) and sends it every message, valid and invalid, asserting
 * what PROTOCOL.md says the server must answer; after each case it checks
 * that an ordinary client is still served. It assumes nothing about the
 * server but what HELLO_OK and VARIANTS announce. The client suite turns
 * this around: a scripted mock server sends libhairfilter every valid and
 * invalid reply and asserts what the library does with it.
 *
 *   cf_options o = {.server = "unix:/run/hairfilterd/hairfilterd.sock"};
 *   cf_summary s;
 *   int rc = cf_run_server(&o, &s);   // 0 when every case passed
 *
 * Each case is named "section.rule[.detail]"; PROTOCOL.md names, next to
 * each rule, the cases that test it (cf_check_doc keeps the two in step).
 */
#ifndef HF_CONFORMANCE_H
#define HF_CONFORMANCE_H

#include <stdio.h>

#ifdef __cplusplus
extern "C" {
#endif

typedef struct cf_options {
  const char *server;      /* URL of the server under test (server suite) */
  const char *token;       /* its TCP token, or NULL */
  const char *tls_ca;      /* tls: URLs: CA file of the server's certificate; NULL: the system's */
  const char *tls_cert;    /* client certificate and key for mutual TLS, or NULL */
  const char *tls_key;
  const char *tls_server_name; /* the name the server's certificate must carry; NULL: the host */
  const char *pattern;     /* run only cases matching this fnmatch pattern; NULL: all */
  int timeout_ms;          /* longest wait for a reply the server owes; 0: 10000 */
  int quiet_ms;            /* how long "no reply" is watched for; 0: 300 */
  int stall_ms;            /* how long the stall cases stay silent; 0: 1500 */
  int verbose;             /* print passing cases too */
  FILE *out;               /* the report: header, verdicts, summary; NULL: stdout */
  const char *junit;       /* also write the verdicts as JUnit XML to this file; NULL: no */
} cf_options;

typedef struct cf_summary {
  int cases, passed, failed, skipped;
} cf_summary;

/* Runs the server suite against o->server. Returns 0 when no case failed,
 * 1 when some did, 2 when the server could not be probed at all (no
 * HELLO_OK, no VARIANTS, no valid RESULT for an ordinary frame: the message
 * says why), when o->pattern matches no case, or when o->junit cannot be
 * written. Prints to o->out a header line, one line per failed or skipped
 * case (every case with verbose) and a summary line
 * "conformance: N cases, P passed, F failed, S skipped". With o->junit,
 * writes the same verdicts as JUnit XML: a <testsuite> with one <testcase>
 * per case run, a failed one holding <failure message="why">, a skipped
 * one <skipped message="why">; when it returns 2 after opening the file,
 * one <testcase name="conformance"> holding <error message="why">. */
int cf_run_server(const cf_options *o, cf_summary *sum);

/* Runs the client suite: libhairfilter against the scripted mock server
 * (server and token are not used). Same return values and output. */
int cf_run_client(const cf_options *o, cf_summary *sum);

/* Prints the names of the cases of one suite (0 server, 1 client), one per
 * line, each followed by a tab and the rule it checks. */
void cf_list(FILE *out, int client_suite);

/* Checks that the document at path (PROTOCOL.md) names every case of both
 * suites, and that every case name it gives (in backquotes, in paragraphs
 * that begin "*Cases:*", a trailing ".*" standing for a family) matches a
 * case. Prints what is
 * missing or unknown; returns the number of problems, or -1 when the file
 * cannot be read. */
int cf_check_doc(const char *path, FILE *out);

#ifdef __cplusplus
}
#endif
#endif /* HF_CONFORMANCE_H */
