/* Test helper: the field cases (tests/data/field) and a temporary directory
 * per test program, by file name. Returned paths live in a small ring of
 * static buffers: good for the next few calls. */
#ifndef HF_TEST_PATHS_H
#define HF_TEST_PATHS_H

/* Path of a field case, e.g. test_field("exr-tiled.exr"). */
const char *test_field(const char *name);
/* Path of another file of tests/data, e.g. test_data("exr-b44-half.exr"). */
const char *test_data(const char *name);
/* Creates the temporary directory /tmp/<prefix>_XXXXXX; 0 or -1. */
int test_tmp_create(const char *prefix);
/* Path of a file in it. */
const char *test_tmp(const char *name);
/* The directory itself. */
const char *test_tmp_dir(void);
/* Removes it and everything in it; 0 or -1. */
int test_tmp_remove(void);

#endif
