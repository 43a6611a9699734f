/*
 * The model repository: which weights files serve which variant names, and
 * how that changes on SIGHUP without dropping a request.
 *
 * The files are those the configuration names (--weights [NAME=]FILE) and
 * every *.safetensors in --weights-dir. A variant's name is the one in its
 * file's metadata unless the configuration gives another, so a retrained
 * Small can be served as Small-retrained beside the bundled Small.
 *
 * A reload (Triton's "explicit model control", driven by a signal) reads the
 * configuration and the directory again and compares each file with what it
 * was when loaded (device, inode, size, modification time):
 *  - a new file is loaded, a changed one loaded again;
 *  - loads run on the worker (the backend's thread), between batches; the
 *    loop keeps admitting requests meanwhile;
 *  - when every load is back, the new models are swapped in at once: new
 *    requests go to the new version, requests already admitted finish on
 *    the one they were admitted for (jobs hold a reference; the last one to
 *    let go hands the model to the worker to be destroyed);
 *  - a file gone from the configuration or the directory is removed the
 *    same way: new requests for its name get UNKNOWN_VARIANT, admitted
 *    ones finish, then it is unloaded;
 *  - a load that fails leaves the version before it serving (or nothing,
 *    for a new file), is logged and counted, and, while no version of that
 *    file serves, /readyz says so;
 *  - a weights directory that cannot be read fails the whole reload and
 *    changes nothing: a mount that went away briefly must not unload every
 *    variant.
 * At start the same code loads everything; there any failure stops the
 * daemon.
 */
#define _GNU_SOURCE
#include <dirent.h>
#include <errno.h>
#include <fcntl.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "server.h"

/* One file the configuration asks for. */
typedef struct want {
  char path[4096];
  const char *override;          /* NULL: the metadata's name */
  hfd_file_id file;
  int stat_errno;                /* 0, or why it could not be looked at */
} want;

static hfd_file_id file_id(const struct stat *st) {
  return (hfd_file_id){(uint64_t)st->st_dev, (uint64_t)st->st_ino, (uint64_t)st->st_size,
                       (int64_t)st->st_mtim.tv_sec * 1000000000 + st->st_mtim.tv_nsec};
}

/* A weights file the daemon's user may not read: "Permission denied" alone
 * does not say that the daemon runs as its own user (hairfilter under
 * systemd, 10001 in the image) while the file was copied in by root with a
 * private mode. Fills why with who the daemon is, the file's owner and
 * mode, and the fix; 0 when the file is readable or that is not the
 * reason (the loader's own message then stands). */
static int explain_unreadable(const char *path, char *why, size_t whylen) {
  int fd = open(path, O_RDONLY | O_CLOEXEC | O_NONBLOCK);   /* a FIFO must not block */
  if (fd >= 0) close(fd);
  if (fd >= 0 || errno != EACCES) return 0;
  struct stat st;
  if (stat(path, &st) != 0) return 0;  /* a directory on the way: the loader says so */
  char user[64];
  hfd_user_name(user, sizeof user);
  snprintf(why, whylen,
           "permission denied: hairfilterd runs as uid %ld (%s) gid %ld and cannot read it "
           "(owner uid %ld gid %ld, mode %04o); weights are not secret: chmod 0644 %s (or "
           "install -m 0644 when copying it in)",
           (long)geteuid(), user, (long)getegid(), (long)st.st_uid, (long)st.st_gid,
           (unsigned)(st.st_mode & 07777), path);
  return 1;
}

static int has_suffix(const char *s, const char *suf) {
  size_t n = strlen(s), m = strlen(suf);
  return n > m && !strcmp(s + n - m, suf);
}

static int cmp_names(const void *a, const void *b) {
  return strcmp(*(char *const *)a, *(char *const *)b);
}

/* The files the configuration names now, explicit ones first, then the
 * directory's in name order (so that variant order is stable); a directory
 * file that is also named explicitly is taken once, with the explicit
 * entry's name. -1 with why when the list cannot be made. */
static int gather(const hfd_config *cfg, want *ws, int *nw, char *why, size_t whylen) {
  int n = 0;
  for (int i = 0; i < cfg->num_weights; i++) {
    want *w = &ws[n++];
    memset(w, 0, sizeof *w);
    snprintf(w->path, sizeof w->path, "%s", cfg->weights[i]);
    w->override = cfg->weights_name[i];
    struct stat st;
    if (stat(w->path, &st) != 0)
      w->stat_errno = errno;
    else
      w->file = file_id(&st);
    /* A loaded model is known by its file (a reload replaces the model of
     * a changed file), so one file cannot serve two names: the second
     * entry would silently replace the first. */
    for (int j = 0; j < n - 1; j++) {
      const want *o = &ws[j];
      int same = !strcmp(o->path, w->path) ||
                 (!o->stat_errno && !w->stat_errno && o->file.dev == w->file.dev &&
                  o->file.ino == w->file.ino);
      if (same) {
        snprintf(why, whylen,
                 "--weights %s%s%s and --weights %s%s%s are the same file: a file serves one "
                 "variant; give the second name a copy of it",
                 o->override ? o->override : "", o->override ? "=" : "", o->path,
                 w->override ? w->override : "", w->override ? "=" : "", w->path);
        return -1;
      }
    }
  }
  int explicit = n;
  if (cfg->weights_dir) {
    DIR *d = opendir(cfg->weights_dir);
    if (!d) {
      snprintf(why, whylen, "--weights-dir %s: %s; give the folder that holds the weights files "
               "(*.safetensors; the bundled ones are installed in share/hairfilter/weights under "
               "the install prefix)", cfg->weights_dir, strerror(errno));
      return -1;
    }
    char *names[HFD_MAX_VARIANTS];
    int k = 0, rc = 0;
    struct dirent *e;
    while ((e = readdir(d)) != NULL) {
      if (e->d_name[0] == '.' || !has_suffix(e->d_name, ".safetensors")) continue;
      if (k == HFD_MAX_VARIANTS || !(names[k] = strdup(e->d_name))) {
        snprintf(why, whylen, "%s holds more than %d weight files", cfg->weights_dir,
                 HFD_MAX_VARIANTS);
        rc = -1;
        break;
      }
      k++;
    }
    closedir(d);
    qsort(names, (size_t)k, sizeof *names, cmp_names);
    int found = 0;
    for (int i = 0; i < k; i++) {
      if (!rc) {
        want w;
        memset(&w, 0, sizeof w);
        struct stat st;
        if ((size_t)snprintf(w.path, sizeof w.path, "%s/%s", cfg->weights_dir, names[i]) >=
            sizeof w.path) {
          snprintf(why, whylen, "path too long in %s", cfg->weights_dir);
          rc = -1;
        } else {
          /* Every *.safetensors entry is a weights file the operator
           * configured: one that is not a regular file (a dangling link, a
           * FIFO, a folder) is loaded too, and fails with its reason,
           * rather than being passed over without a word. */
          if (stat(w.path, &st) != 0) w.stat_errno = errno;
          else w.file = file_id(&st);
          found++;
          int dup = 0;
          for (int j = 0; j < explicit && !w.stat_errno; j++)
            dup |= !ws[j].stat_errno && ws[j].file.dev == w.file.dev &&
                   ws[j].file.ino == w.file.ino;
          if (!dup && n == HFD_MAX_VARIANTS) {
            snprintf(why, whylen, "more than %d weight files", HFD_MAX_VARIANTS);
            rc = -1;
          } else if (!dup) {
            ws[n++] = w;
          }
        }
      }
      free(names[i]);
    }
    if (rc) return -1;
    if (!found && !explicit) {
      snprintf(why, whylen, "no *.safetensors in %s: copy the weights files there, or give the "
               "folder that holds them (--weights-dir, or each file with --weights)",
               cfg->weights_dir);
      return -1;
    }
  }
  *nw = n;
  return 0;
}

int hfd_variant_find(const hfd_server *s, const char *name) {
  for (int i = 0; i < s->num_variants; i++)
    if (s->variants[i].model && !strcmp(s->variants[i].name, name)) return i;
  return -1;
}

/* The model serving a file now, if any. */
static hfd_model *serving_path(const hfd_server *s, const char *path) {
  for (int i = 0; i < s->num_variants; i++)
    if (s->variants[i].model && !strcmp(s->variants[i].model->path, path))
      return s->variants[i].model;
  return NULL;
}

/* The slot for name: the one that had it (its counters go on), else a free
 * one (its counters start again), else a new one; -1 when all are taken. */
static int slot_for(hfd_server *s, const char *name) {
  int free_slot = -1;
  for (int i = 0; i < s->num_variants; i++) {
    hfd_variant *v = &s->variants[i];
    if (!strcmp(v->name, name) && (v->model || v->models)) return i;
    if (free_slot < 0 && !v->model && !v->models) free_slot = i;
  }
  if (free_slot < 0) {
    if (s->num_variants == HFD_MAX_VARIANTS) return -1;
    free_slot = s->num_variants++;
  }
  hfd_variant *v = &s->variants[free_slot];
  memset(v, 0, sizeof *v);
  snprintf(v->name, sizeof v->name, "%s", name);
  snprintf(v->stats.name, sizeof v->stats.name, "%s", name);
  return free_slot;
}

void hfd_model_unref(hfd_server *s, hfd_model *m) {
  /* Once the worker has stopped, it has freed every model itself. */
  if (s->stopped) return;
  if (--m->refs > 0) return;
  if (m->slot >= 0) s->variants[m->slot].models--;
  hfd_ctl *c = calloc(1, sizeof *c);
  if (!c) {
    /* Kept until the worker stops, which frees it; only memory is lost. */
    hfd_err("out of memory to unload variant %s; it stays loaded", m->name);
    return;
  }
  c->op = HFD_CTL_UNLOAD;
  c->model = m;
  hfd_worker_control(&s->worker, c);
}

/* Takes a slot's current model out of service: new requests no longer find
 * it, admitted ones keep it alive. */
static void retire(hfd_server *s, int slot) {
  hfd_model *m = s->variants[slot].model;
  s->variants[slot].model = NULL;
  hfd_model_unref(s, m);
}

static void install(hfd_server *s, int slot, hfd_model *m) {
  m->slot = slot;
  m->refs = 1;  /* the slot's */
  s->variants[slot].model = m;
  s->variants[slot].models++;
}

/* Queues a load of w on the worker; the ctl comes back through
 * hfd_models_on_loaded (or hfd_worker_take_ctl at start). */
static hfd_ctl *queue_load(hfd_server *s, const want *w) {
  hfd_ctl *c = calloc(1, sizeof *c);
  hfd_model *m = calloc(1, sizeof *m);
  char *path = strdup(w->path);
  if (!c || !m || !path) {
    free(c);
    free(m);
    free(path);
    return NULL;
  }
  m->path = path;
  m->slot = -1;
  if (w->override) snprintf(m->override, sizeof m->override, "%s", w->override);
  c->op = HFD_CTL_LOAD;
  c->model = m;
  hfd_worker_control(&s->worker, c);
  return c;
}

static void free_failed(hfd_ctl *c) {
  free(c->model->path);
  free(c->model);
  free(c);
}

/* A load that came back built but cannot be installed: it goes back to the
 * worker to be destroyed. */
static void discard_built(hfd_server *s, hfd_ctl *c) {
  c->model->refs = 1;
  hfd_model_unref(s, c->model);
  free(c);
}

static void log_variant(const hfd_server *s, const char *what, const hfd_model *m) {
  char levels[128] = "", kv[512] = "";
  for (int l = 0; l < m->cfg.num_levels; l++) {
    size_t used = strlen(levels);
    snprintf(levels + used, sizeof levels - used, "%s%d", l ? "," : "", m->cfg.levels[l]);
  }
  hfd_kv(kv, sizeof kv, "file", m->path);
  hfd_log("variant %s: %s%d spp%s, levels %s, %s on %s%s", m->name, what, m->cfg.spp,
          m->cfg.estimate ? " and the alpha-corrected estimate (protocol version 3)" : "",
          levels, m->precision, hf_backend_name(s->worker.backend), kv);
}

/* Applies loads that are all back (loads[i] for ws[i], some NULL: kept as
 * they were) and removes what no longer has a file. strict (the start):
 * any failure is an error and -1. Returns the number of failures. */
static int apply(hfd_server *s, const want *ws, int nw, hfd_ctl **loads, hfd_model **gone,
                 int ngone, int strict) {
  int failed = 0, loaded = 0, replaced = 0, removed = 0;
  /* Removals first, so a name can move from a file that went to one that
   * came in the same reload. */
  for (int i = 0; i < ngone; i++) {
    hfd_model *m = gone[i];
    if (m->slot < 0 || s->variants[m->slot].model != m) continue;
    char kv[300] = "";
    hfd_kv(kv, sizeof kv, "file", m->path);
    hfd_log("variant %s: removed; unloaded once its admitted requests are answered%s", m->name,
            kv);
    retire(s, m->slot);
    removed++;
  }
  s->missing = 0;
  s->missing_why[0] = 0;
  for (int i = 0; i < nw; i++) {
    hfd_ctl *c = loads[i];
    char kv[300] = "";
    hfd_kv(kv, sizeof kv, "file", ws[i].path);
    if (!c) continue;  /* unchanged, still serving */
    hfd_model *old = serving_path(s, ws[i].path);
    if (c->rc) {
      failed++;
      s->loads_failed++;
      /* The loader's message may already start with the file's path. */
      size_t pl = strlen(ws[i].path);
      const char *why = strncmp(c->msg, ws[i].path, pl) || strncmp(c->msg + pl, ": ", 2)
                            ? c->msg : c->msg + pl + 2;
      char denied[600], listed[600];
      if (explain_unreadable(ws[i].path, denied, sizeof denied)) why = denied;
      /* `--weights a,b` (as `hairfilter eval --weights` takes a list): the
       * daemon takes one file per --weights. */
      struct stat lst;
      if (strchr(ws[i].path, ',') && stat(ws[i].path, &lst) != 0 && errno == ENOENT) {
        snprintf(listed, sizeof listed, "%.500s (one file per --weights: give --weights once for "
                 "each, or --weights-dir DIR)", why);
        why = listed;
      }
      if (strict) {
        /* At start every configured file must load (docs/SERVER.md,
         * "Reload"): say so, and where the file came from to fix it. */
        hfd_err("weights file %s: %s; every configured weights file must load at start: fix "
                "it, or take it out of --weights or --weights-dir", ws[i].path, why);
      } else if (old) {
        hfd_err("reload: %s: %s; variant %s keeps serving the version loaded before%s",
                ws[i].path, why, old->name, kv);
      } else {
        hfd_err("reload: %s: %s; not served%s", ws[i].path, why, kv);
      }
      if (!old && !s->missing++)
        snprintf(s->missing_why, sizeof s->missing_why, "%.100s: %.190s", ws[i].path, why);
      free_failed(c);
      loads[i] = NULL;
      continue;
    }
    hfd_model *m = c->model;
    int other = hfd_variant_find(s, m->name);
    if (other >= 0 && s->variants[other].model != old) {
      failed++;
      s->loads_failed++;
      const char *by = s->variants[other].model->path;
      if (strict)
        hfd_err("%s: a variant named '%s' is already loaded (from %s); name one of them with "
                "--weights NAME=FILE", ws[i].path, m->name, by);
      else
        hfd_err("reload: %s: a variant named '%s' is already served (from %s); name one of "
                "them in the --config file (weights = NAME=FILE) and reload again, or at the "
                "next start with --weights NAME=FILE%s", ws[i].path, m->name, by, kv);
      if (!old && !s->missing++)
        snprintf(s->missing_why, sizeof s->missing_why, "%s: variant name '%s' taken by %s",
                 ws[i].path, m->name, by);
      discard_built(s, c);
      loads[i] = NULL;
      continue;
    }
    if (old && strcmp(old->name, m->name)) {
      /* The file now names another variant: the old name goes. */
      retire(s, old->slot);
      removed++;
      old = NULL;
    }
    int slot = old ? old->slot : slot_for(s, m->name);
    if (slot < 0) {
      failed++;
      s->loads_failed++;
      hfd_err("%s%s: more than %d variants%s", strict ? "" : "reload: ", ws[i].path,
              HFD_MAX_VARIANTS, kv);
      discard_built(s, c);
      loads[i] = NULL;
      continue;
    }
    if (old) {
      retire(s, slot);
      replaced++;
    } else {
      loaded++;
    }
    install(s, slot, m);
    s->loads_ok++;
    log_variant(s, strict ? "" : old ? "replaced: " : "loaded: ", m);
    free(c);
    loads[i] = NULL;
  }
  int serving = 0;
  for (int i = 0; i < s->num_variants; i++) serving += s->variants[i].model != NULL;
  if (!strict) {
    char kv[200];
    snprintf(kv, sizeof kv, " serving=%d loaded=%d replaced=%d removed=%d failed=%d%s", serving,
             loaded, replaced, removed, failed, s->reload.tls_failed ? " tls=failed" : "");
    if (failed || s->reload.tls_failed)
      hfd_warn("reload done with %d failure(s):%s", failed + s->reload.tls_failed, kv);
    else
      hfd_notice("reload done:%s", kv);
  }
  return failed;
}

/* Decides what to load and what to remove; queues the loads. */
static int plan(hfd_server *s, want *ws, int nw, hfd_ctl **loads, hfd_model **gone, int *ngone) {
  int queued = 0;
  for (int i = 0; i < nw; i++) {
    loads[i] = NULL;
    const want *w = &ws[i];
    hfd_model *cur = serving_path(s, w->path);
    if (cur && !w->stat_errno && !memcmp(&cur->file, &w->file, sizeof w->file) &&
        !strcmp(cur->override, w->override ? w->override : ""))
      continue;  /* unchanged */
    if (!(loads[i] = queue_load(s, w))) {
      hfd_err("out of memory to load %s", w->path);
      continue;
    }
    queued++;
  }
  *ngone = 0;
  for (int i = 0; i < s->num_variants; i++) {
    hfd_model *m = s->variants[i].model;
    if (!m) continue;
    int kept = 0;
    for (int k = 0; k < nw && !kept; k++) kept = !strcmp(ws[k].path, m->path);
    if (!kept) gone[(*ngone)++] = m;
  }
  return queued;
}

int hfd_models_load_initial(hfd_server *s) {
  static want ws[HFD_MAX_VARIANTS];
  hfd_ctl *loads[HFD_MAX_VARIANTS];
  hfd_model *gone[HFD_MAX_VARIANTS];
  int nw = 0, ngone = 0;
  char why[600];
  if (gather(s->cfg, ws, &nw, why, sizeof why)) {
    hfd_err("%s", why);
    return -1;
  }
  int queued = plan(s, ws, nw, loads, gone, &ngone);
  for (int back = 0; back < queued;) {
    for (hfd_ctl *c = hfd_worker_take_ctl(&s->worker, 1); c; c = c->next) back++;
  }
  if (atomic_load(&s->worker.abandon)) {
    /* A stop came meanwhile: the loads after it failed at once, and the
     * daemon will not serve, so none is installed (the worker frees the
     * models it built when it stops). */
    int built = 0;
    for (int i = 0; i < nw; i++)
      if (loads[i]) {
        built += loads[i]->rc == 0;
        loads[i]->next = NULL;
        hfd_ctl_free_list(loads[i]);
      }
    hfd_log("stopping: %d of %d weights file(s) loaded", built, nw);
    return 1;
  }
  int failed = apply(s, ws, nw, loads, gone, ngone, 1);
  s->load_started = 1;
  return failed || queued < nw ? -1 : 0;
}

/* What a reload in flight is waiting for. */
static struct {
  want ws[HFD_MAX_VARIANTS];
  hfd_ctl *loads[HFD_MAX_VARIANTS];
  hfd_model *gone[HFD_MAX_VARIANTS];
  int nw, ngone;
} pending;

/* Frees the reload's loads, none swapped in: the daemon is draining, and
 * the loads still to do were given up (hfd_worker_abandon_loads). The
 * models built go when the worker stops. */
static void drop_reload(hfd_server *s) {
  int built = 0, files = 0;
  for (int i = 0; i < pending.nw; i++) {
    hfd_ctl *c = pending.loads[i];
    pending.loads[i] = NULL;
    if (!c) continue;
    files++;
    built += c->rc == 0;
    c->next = NULL;
    hfd_ctl_free_list(c);
  }
  s->reload.active = 0;
  hfd_log("reload: given up for the stop: %d of %d file(s) loaded, none swapped in", built,
          files);
}

static void finish_reload(hfd_server *s) {
  if (s->draining) {
    drop_reload(s);
    return;
  }
  int failed = apply(s, pending.ws, pending.nw, pending.loads, pending.gone, pending.ngone, 0);
  s->reload.active = 0;
  if (failed || s->reload.tls_failed)
    s->reloads_failed++;
  else
    s->reloads_ok++;
  hfd_limits_derive(s);
  if (!s->draining) hfd_notify_ready(s);
  if (s->reload.again && !s->draining) {
    s->reload.again = 0;
    hfd_models_reload(s);
  }
}

void hfd_models_on_loaded(hfd_server *s, hfd_ctl *c) {
  /* Each LOAD ctl is in pending.loads already; it is marked done. */
  (void)c;
  if (!s->reload.active || --s->reload.pending > 0) return;
  finish_reload(s);
}

/* A key the reload does not take, changed in the configuration: one line
 * each, naming it with the value that keeps serving and the one the next
 * start will use. */
static void restart_needed(const char *key, const char *was, const char *now) {
  hfd_warn("reload: --%s changed from %s to %s; it takes effect at the next start, and %s "
           "stays until then", key, was, now, was);
}

static void restart_str(const char *key, const char *was, const char *now) {
  if (!was) was = "(none)";
  if (!now) now = "(none)";
  if (strcmp(was, now)) restart_needed(key, was, now);
}

static void restart_int(const char *key, long long was, long long now) {
  if (was == now) return;
  char a[32], b[32];
  snprintf(a, sizeof a, "%lld", was);
  snprintf(b, sizeof b, "%lld", now);
  restart_needed(key, a, b);
}

static void restart_flag(const char *key, int was, int now) {
  if (!was != !now) restart_needed(key, was ? "yes" : "no", now ? "yes" : "no");
}

static void listen_list(const hfd_config *c, char *buf, size_t cap) {
  buf[0] = 0;
  for (int i = 0; i < c->num_listen; i++)
    snprintf(buf + strlen(buf), cap - strlen(buf), "%s%s", i ? " " : "", c->listen[i]);
}

static void warm_list(const hfd_config *c, char *buf, size_t cap) {
  snprintf(buf, cap, "%s", c->num_warm ? "" : "(none)");
  for (int i = 0; i < c->num_warm; i++)
    snprintf(buf + strlen(buf), cap - strlen(buf), "%s%dx%dx%d", i ? "," : "", c->warm[i].width,
             c->warm[i].height, c->warm[i].batch);
}

/* The keys a reload takes from the configuration (weights, names, the
 * token, TLS files, the log level); every other key needs a restart, and
 * each that changed is named with its old and new values. */
static void take_reloadable(hfd_server *s, hfd_config *n) {
  hfd_config *c = s->cfg;
  char a[2048], b[2048];
  listen_list(c, a, sizeof a);
  listen_list(n, b, sizeof b);
  restart_str("listen", a, b);
  restart_str("backend", c->backend, n->backend);
  /* Without --max-batch the backend's default serves, whatever it is. */
  if (n->max_batch) restart_int("max-batch", c->max_batch, n->max_batch);
  restart_int("max-queue-delay-us", c->max_queue_delay_us, n->max_queue_delay_us);
  restart_int("queue-size", c->queue_size, n->queue_size);
  restart_int("max-inflight", c->max_inflight, n->max_inflight);
  snprintf(a, sizeof a, "%dx%d", c->max_width, c->max_height);
  snprintf(b, sizeof b, "%dx%d", n->max_width, n->max_height);
  restart_str("max-size", a, b);
  restart_int("max-frame-mb", (long long)(c->max_frame_bytes >> 20),
              (long long)(n->max_frame_bytes >> 20));
  restart_int("max-memory-mb", (long long)(c->max_memory_bytes >> 20),
              (long long)(n->max_memory_bytes >> 20));
  restart_int("max-shm-mb", (long long)(c->max_shm_bytes >> 20),
              (long long)(n->max_shm_bytes >> 20));
  restart_int("max-shm-mb-per-connection", (long long)(c->max_shm_conn_bytes >> 20),
              (long long)(n->max_shm_conn_bytes >> 20));
  restart_int("max-shm-mb-per-client", (long long)(c->max_shm_client_bytes >> 20),
              (long long)(n->max_shm_client_bytes >> 20));
  restart_int("max-connections", c->max_connections, n->max_connections);
  restart_int("max-handshakes", c->max_handshakes, n->max_handshakes);
  snprintf(a, sizeof a, "%d", c->max_handshakes_addr);
  snprintf(b, sizeof b, "%d", n->max_handshakes_addr);
  restart_str("max-handshakes-per-address", c->max_handshakes_addr ? a : "(default)",
              n->max_handshakes_addr ? b : "(default)");
  restart_int("ipv6-client-prefix", c->ipv6_client_prefix, n->ipv6_client_prefix);
  restart_str("queue-share-by", c->share_by_connection ? "connection" : "client",
              n->share_by_connection ? "connection" : "client");
  restart_flag("no-auth", c->no_auth, n->no_auth);
  restart_flag("tls-client-cert-auth", c->tls_client_cert_auth, n->tls_client_cert_auth);
  restart_int("drain-timeout-ms", c->drain_timeout_ms, n->drain_timeout_ms);
  restart_int("flush-timeout-ms", c->flush_timeout_ms, n->flush_timeout_ms);
  restart_int("handshake-timeout-ms", c->handshake_timeout_ms, n->handshake_timeout_ms);
  restart_int("stall-timeout-ms", c->stall_timeout_ms, n->stall_timeout_ms);
  restart_int("min-recv-rate", (long long)(c->min_recv_rate >> 10),
              (long long)(n->min_recv_rate >> 10));
  restart_str("ready-file", c->ready_file, n->ready_file);
  restart_str("name", c->name, n->name);
  restart_str("http", c->http, n->http);
  restart_int("watchdog-ms", c->watchdog_ms, n->watchdog_ms);
  restart_int("pipeline-depth", c->pipeline_depth, n->pipeline_depth);
  warm_list(c, a, sizeof a);
  warm_list(n, b, sizeof b);
  restart_str("warm", a, b);
  memcpy(c->weights, n->weights, sizeof c->weights);
  memcpy(c->weights_name, n->weights_name, sizeof c->weights_name);
  c->num_weights = n->num_weights;
  c->weights_dir = n->weights_dir;
  if (strcmp(c->token, n->token)) {
    /* Connections already past their HELLO stay; new ones need the new token. */
    memcpy(c->token, n->token, sizeof c->token);
    hfd_notice("reload: the token changed; new TCP connections need the new one");
  }
  /* Certificates are read again: a renewed one serves new connections. */
  c->tls_cert = n->tls_cert;
  c->tls_key = n->tls_key;
  c->tls_client_ca = n->tls_client_ca;
  /* A certificate renewal that did not load is a failed reload: the old
   * certificate serves on towards its end date, and an operator alerting
   * on hairfilterd_reloads_total{result="failed"} must see it. */
  s->reload.tls_failed = hfd_tls_reload(s, n) != 0;
  if (c->log_level != n->log_level) {
    c->log_level = n->log_level;
    hfd_log_level = n->log_level;
    hfd_notice("reload: log level %s", hfd_log_level_name(n->log_level));
  }
  /* The strings of the new config (the file's lines) are kept: c points
   * into them now. Those of the reload before are no longer used. */
  static hfd_config last;
  hfd_config_free(&last);
  last.owned = n->owned;
  last.num_owned = n->num_owned;
  last.cap_owned = n->cap_owned;
  n->owned = NULL;
  n->num_owned = n->cap_owned = 0;
}

void hfd_models_reload(hfd_server *s) {
  if (s->draining) {
    /* Said, so that a reload sent by hand during a stop is not taken as
     * done. */
    hfd_notice("SIGHUP: ignored while draining; the configuration and the weights are read "
               "at the next start");
    return;
  }
  if (s->reload.active) {
    s->reload.again = 1;
    hfd_log("SIGHUP: a reload is in progress; another follows it");
    return;
  }
  hfd_notify_reloading();
  hfd_notice("SIGHUP: reading the configuration%s%s and the weights again",
             s->cfg->config_path ? " " : "", s->cfg->config_path ? s->cfg->config_path : "");
  static hfd_config n;
  memset(&n, 0, sizeof n);
  /* The same command line, and the config file as it is now. */
  int rc = hfd_config_parse(s->argc, s->argv, &n);
  if (rc) {
    hfd_err("reload: the configuration has errors (above); nothing changed");
    hfd_config_free(&n);
    s->reloads_failed++;
    hfd_notify_ready(s);
    return;
  }
  char why[600];
  int nw = 0;
  if (gather(&n, pending.ws, &nw, why, sizeof why)) {
    hfd_err("reload: %s; nothing changed", why);
    hfd_config_free(&n);
    s->reloads_failed++;
    hfd_notify_ready(s);
    return;
  }
  take_reloadable(s, &n);
  pending.nw = nw;
  int queued = plan(s, pending.ws, nw, pending.loads, pending.gone, &pending.ngone);
  s->reload.active = 1;
  s->reload.pending = queued;
  if (queued == 0) finish_reload(s);
}

void hfd_models_after_stop(hfd_server *s) {
  for (int i = 0; i < s->num_variants; i++) {
    s->variants[i].served_at_stop = s->variants[i].model != NULL;
    s->variants[i].model = NULL;
  }
  if (s->reload.active) drop_reload(s);
}
