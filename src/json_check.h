/* Internal to src/: checks on parsed JSON (cJSON) that the parser does not
 * make, for every JSON text the library reads from a file. */
#ifndef HF_JSON_CHECK_H
#define HF_JSON_CHECK_H

#include <stddef.h>

#include <cjson/cJSON.h>

/* The first key named twice in one object anywhere in node, or NULL; *where
 * gets that object's own key ("" for the top level or an array element). */
const char *hf_json_duplicate(const cJSON *node, const char **where);
/* The JSON value that text's len bytes hold (cJSON_Delete it), or NULL
 * when they hold none or anything but JSON's whitespace follows it. */
cJSON *hf_json_one_value(const char *text, size_t len);
/* "a string", "a number", "an object", ... of v, for messages. */
const char *hf_json_kind(const cJSON *v);

#endif
