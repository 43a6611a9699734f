/* Replays files through a fuzz target's LLVMFuzzerTestOneInput: the seed
 * corpus and every regression input, on every ctest run, with whichever
 * compiler and sanitizers the tree was built with. Arguments are files or
 * directories (read one level deep). Exits 0 when every input ran; a
 * target that finds a fault aborts. */
#define _POSIX_C_SOURCE 200809L
#include <dirent.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

static int run_file(const char *path) {
  FILE *f = fopen(path, "rb");
  if (!f) {
    fprintf(stderr, "fuzz_replay: cannot read %s\n", path);
    return -1;
  }
  struct stat st;
  if (fstat(fileno(f), &st) || st.st_size > (1 << 26)) {
    fclose(f);
    fprintf(stderr, "fuzz_replay: %s is not a file of at most 64 MiB\n", path);
    return -1;
  }
  size_t n = (size_t)st.st_size;
  uint8_t *buf = malloc(n ? n : 1);
  if (!buf || fread(buf, 1, n, f) != n) {
    free(buf);
    fclose(f);
    fprintf(stderr, "fuzz_replay: cannot read %s\n", path);
    return -1;
  }
  fclose(f);
  LLVMFuzzerTestOneInput(buf, n);
  free(buf);
  return 0;
}

int main(int argc, char **argv) {
  int files = 0, bad = 0;
  for (int i = 1; i < argc; i++) {
    struct stat st;
    if (stat(argv[i], &st)) continue;   /* an empty regression folder is not made */
    if (!S_ISDIR(st.st_mode)) {
      bad |= run_file(argv[i]);
      files++;
      continue;
    }
    DIR *d = opendir(argv[i]);
    struct dirent *e;
    while (d && (e = readdir(d))) {
      if (e->d_name[0] == '.' || !strcmp(e->d_name, "README.md")) continue;
      char path[4096];
      snprintf(path, sizeof path, "%s/%s", argv[i], e->d_name);
      bad |= run_file(path);
      files++;
    }
    if (d) closedir(d);
  }
  printf("fuzz_replay: %d input(s) replayed\n", files);
  return bad || files == 0 ? 1 : 0;
}
