/* hairfilter conformance: the protocol conformance suite (tests/conformance)
 * against any server, or against libhairfilter with its mock server. */
#include <getopt.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "cli_args.h"
#include "commands.h"

#ifdef HF_HAVE_CONFORMANCE
#include "conformance.h"

static void usage(FILE *f) {
  fprintf(f,
          "usage: hairfilter conformance --server URL [--token T] [options]\n"
          "       hairfilter conformance --client [options]\n"
          "       hairfilter conformance --list [--client] | --check-doc PROTOCOL.md\n"
          "\n"
          "Checks a server against protocol/PROTOCOL.md rule by rule (one case per\n"
          "rule, valid and invalid messages, every byte of every frame cut short,\n"
          "stalls and disconnects at every stage), or, with --client, libhairfilter\n"
          "against a scripted mock server. After each server case an ordinary client\n"
          "must still be served. Prints a header line, the failed and skipped cases\n"
          "and a summary, all to stdout; exits 0 when none failed, 1 when some did,\n"
          "2 when the server cannot be probed, no case matches --case, or an option\n"
          "is wrong. It assumes nothing of the server beyond HELLO_OK and VARIANTS.\n"
          "\n"
          "  --server URL     unix:PATH, tcp:HOST:PORT, tls:HOST:PORT or tcp:PORT\n"
          "  --token T        the TCP listener's token (default $HAIRFILTER_TOKEN)\n"
          CLI_TLS_USAGE
          "  --case PATTERN   only cases whose name matches (shell pattern, e.g. 'shm.*');\n"
          "                   a pattern that matches none exits 2\n"
          "  --junit FILE     also write the verdicts as JUnit XML (one testcase per case,\n"
          "                   failures and skips with their reasons) for CI\n"
          "  --timeout DUR    longest wait for a reply the server owes (default 10s)\n"
          "  --quiet DUR      how long 'no reply' is watched for (default 300ms)\n"
          "  --stall DUR      how long the stall cases stay silent (default 1500ms);\n"
          "                   longer than the server's deadlines to see them act\n"
          "  --verbose        print every case with its time\n"
          "Durations take a unit: 10s, 300ms, 1m. A plain number is MILLISECONDS (unlike\n"
          "hairfilter load's seconds), so one below 100 is refused: --timeout 10 would\n"
          "be 10 ms; write 10s, or 10ms if that is meant.\n");
}

/* A duration written without a unit. */
static int plain_number(const char *s) {
  return *s && s[strspn(s, "0123456789.")] == 0;
}

int cmd_conformance(int argc, char **argv) {
  static const struct option opts[] = {
    {"server", required_argument, 0, 's'}, {"token", required_argument, 0, 'k'},
    {"client", no_argument, 0, 'c'},       {"case", required_argument, 0, 'p'},
    {"list", no_argument, 0, 'l'},         {"check-doc", required_argument, 0, 'd'},
    {"timeout", required_argument, 0, 't'}, {"quiet", required_argument, 0, 'q'},
    {"stall", required_argument, 0, 'S'},  {"verbose", no_argument, 0, 'v'},
    {"junit", required_argument, 0, 'j'},  {"help", no_argument, 0, 'h'},
    CLI_TLS_LONG_OPTIONS,
    {0, 0, 0, 0},
  };
  cf_options o = {0};
  o.token = getenv("HAIRFILTER_TOKEN");
  int client = 0, list = 0;
  cli_tls tls = {0};
  const char *doc = NULL;
  double secs;
  opterr = 0;
  optind = 1;
  int ch;
  while ((ch = getopt_long(argc, argv, ":hv", opts, NULL)) != -1) {
    switch (ch) {
      case 's': o.server = optarg; break;
      case 'k': o.token = optarg; break;
      case 'c': client = 1; break;
      case 'p': o.pattern = optarg; break;
      case 'l': list = 1; break;
      case 'd': doc = optarg; break;
      case 'v': o.verbose = 1; break;
      case 'j': o.junit = optarg; break;
      case 't':
      case 'q':
      case 'S': {
        const char *opt = ch == 't' ? "--timeout" : ch == 'q' ? "--quiet" : "--stall";
        if (cli_arg_duration("hairfilter conformance", opt, optarg, 1e-3, 1e-3, 3600, &secs))
          return 2;
        if (plain_number(optarg) && secs < 0.1) {
          /* hairfilter load counts plain numbers in seconds: "--timeout 10"
           * meant as 10 s must not run with 10 ms. */
          fprintf(stderr,
                  "hairfilter conformance: %s %s: a plain number is milliseconds here, and %s ms "
                  "is too short to be meant; write %ss for seconds, or %sms if you mean "
                  "milliseconds\n", opt, optarg, optarg, optarg, optarg);
          return 2;
        }
        *(ch == 't' ? &o.timeout_ms : ch == 'q' ? &o.quiet_ms : &o.stall_ms) = (int)(secs * 1e3 + 0.5);
        break;
      }
      case 'h': usage(stdout); return 0;
      case ':': cli_arg_bad_option("hairfilter conformance", argv, optind, optopt, 1); return 2;
      default:
        if (cli_tls_option(ch, optarg, &tls)) break;
        cli_arg_bad_option("hairfilter conformance", argv, optind, optopt, 0);
        return 2;
    }
  }
  if (optind < argc) {
    fprintf(stderr, "hairfilter conformance: unexpected argument '%s'\n", argv[optind]);
    return 2;
  }
  if (cli_tls_pair("hairfilter conformance", tls.cert, tls.key)) return 2;
  if (cli_tls_for_server("hairfilter conformance", o.server, &tls)) return 2;
  o.tls_ca = tls.ca;
  o.tls_cert = tls.cert;
  o.tls_key = tls.key;
  o.tls_server_name = tls.server_name;
  if (doc) return cf_check_doc(doc, stdout) == 0 ? 0 : 1;
  if (list) {
    cf_list(stdout, client);
    return 0;
  }
  if (o.token && !*o.token) o.token = NULL;
  cf_summary s;
  if (client) return cf_run_client(&o, &s);
  if (!o.server) {
    fprintf(stderr, "hairfilter conformance: give --server URL (or --client)\n");
    usage(stderr);
    return 2;
  }
  return cf_run_server(&o, &s);
}

#else

int cmd_conformance(int argc, char **argv) {
  (void)argc;
  (void)argv;
  fprintf(stderr, "hairfilter conformance: this hairfilter was built without the test suite "
                  "(-DHF_BUILD_TESTS=OFF); use a build with it\n");
  return 2;
}

#endif
