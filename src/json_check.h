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
/* Why text's len bytes cannot be read as JSON here although a JSON parser
 * might take them, or NULL: a byte that is not UTF-8 (JSON text is UTF-8;
 * safetensors' reference reader refuses other bytes, cJSON passes them),
 * or a \u0000 escape, which cJSON cuts a C string at, so "a\u0000b" would
 * be read as "a" where other readers see another name. *at gets its
 * offset. */
const char *hf_json_text_fault(const char *text, size_t len, size_t *at);
/* "a string", "a number", "an object", ... of v, for messages. */
const char *hf_json_kind(const cJSON *v);

#endif
