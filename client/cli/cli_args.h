/* Strict parsing of option values for the CLI subcommands: the whole
 * argument must be the value, inside its range, and a unit the parser does
 * not know is refused, never dropped (so `--seconds 1x` is an error, not 1
 * second). Each function prints one line naming the command, the option
 * and the value on failure and returns -1; 0 on success. cmd is the command
 * as typed ("hairfilter eval", or a tool's own name: "hairfilter-load"),
 * which starts every message. */
#ifndef HF_CLI_ARGS_H
#define HF_CLI_ARGS_H

/* An integer in lo..hi. */
int cli_arg_long(const char *cmd, const char *opt, const char *s, long lo, long hi, long *out);
/* A finite number in lo..hi. */
int cli_arg_double(const char *cmd, const char *opt, const char *s, double lo, double hi,
                   double *out);
/* A duration: a number followed by a unit (h, m or min, s, ms, us), or a
 * plain number, which counts in units of plain_unit_s seconds (1 for an
 * option given in seconds, 1e-3 for one in milliseconds). Result in seconds,
 * in lo_s..hi_s. */
int cli_arg_duration(const char *cmd, const char *opt, const char *s, double plain_unit_s,
                     double lo_s, double hi_s, double *seconds);
/* A range start[:end[:step]] of numbers in lo..hi (integers when integer is
 * set): end defaults to start, step to 1; start <= end, step > 0. */
int cli_arg_range(const char *cmd, const char *opt, const char *s, double lo, double hi,
                  int integer, double out[3]);
/* The error for what getopt_long (with opterr 0 and a ':' optstring)
 * refused: an unknown option or one missing its value, named as written:
 * argv[optind - 1] for a long option, optopt for a short one. */
void cli_arg_bad_option(const char *cmd, char **argv, int optind_now, int optopt_now,
                        int missing_value);

/* The TLS options of every command that connects (tls:HOST:PORT URLs):
 * getopt codes and their usage lines. */
enum { CLI_TLS_CA = 0x1001, CLI_TLS_CERT, CLI_TLS_KEY, CLI_TLS_SERVER_NAME };
#define CLI_TLS_USAGE                                                                  \
  "  --tls-ca FILE    tls: URLs: PEM CA certificates the server's must chain to\n"     \
  "                   (default: the system's); its host name is checked too\n"        \
  "  --tls-server-name NAME  the name the server's certificate must carry\n"          \
  "                   (default: the URL's host)\n"                                     \
  "  --tls-cert FILE  client certificate for mutual TLS (PEM), with --tls-key\n"       \
  "  --tls-key FILE   its private key (PEM)\n"
/* Their long options, for a command's getopt_long table (needs <getopt.h>). */
#define CLI_TLS_LONG_OPTIONS                                                   \
  {"tls-ca", required_argument, 0, CLI_TLS_CA},                                \
  {"tls-cert", required_argument, 0, CLI_TLS_CERT},                            \
  {"tls-key", required_argument, 0, CLI_TLS_KEY},                              \
  {"tls-server-name", required_argument, 0, CLI_TLS_SERVER_NAME}
/* Their values (file paths and a host name, NULL when not given). */
typedef struct cli_tls {
  const char *ca, *cert, *key, *server_name;
} cli_tls;
/* 1 when the getopt code ch is one of the TLS options (arg stored in t),
 * else 0. */
int cli_tls_option(int ch, const char *arg, cli_tls *t);
/* 0, or -1 after saying so when only one of --tls-cert and --tls-key is
 * given (cmd as above). */
int cli_tls_pair(const char *cmd, const char *cert, const char *key);
/* 0, or -1 after saying so when a TLS option is given and no endpoint of
 * server (a URL, or a comma-separated list; NULL: none) is tls:, where it
 * would be ignored and the connection plain (cmd as above). */
int cli_tls_for_server(const char *cmd, const char *server, const cli_tls *t);

#endif
