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
 * a \u0000 escape, which cJSON cuts a C string at, so "a\u0000b" would
 * be read as "a" where other readers see another name, or a lone half of
 * a UTF-16 surrogate pair (\uD800 not followed by \uDC00-\uDFFF, or
 * \uDC00 alone), which cJSON refuses and Python's json takes; or a number
 * JSON's grammar does not allow ("016", "1.", "-.5"), which cJSON reads
 * with strtod and Python's json refuses. *at gets its offset. */
const char *hf_json_text_fault(const char *text, size_t len, size_t *at);
/* The offset in text (valid JSON, len bytes) of the first number written
 * with a fraction or an exponent ("32.0", "3.2e1") in an array that is the
 * value of one of keys in an object that is a member of the top object
 * (a safetensors tensor's "shape" or "data_offsets"), or -1: such numbers
 * are integers to cJSON and Python's == alike, but not to safetensors'
 * reference reader. outer gets that member's key, *key the matching key,
 * *tok_len the number's length. Keys are compared as decoded ("sh\u0061pe"
 * is "shape"). */
long hf_json_nonint_member(const char *text, size_t len, const char *const *keys, int nkeys,
                           char *outer, size_t outer_len, const char **key, size_t *tok_len);
/* The offset in text (valid JSON, len bytes: one object) of the first
 * number written with a fraction or an exponent that is the value of one of
 * keys in the top object, or an element of an array that is ("spp": 4.0,
 * "levels": [32.0]), or -1. *key gets the matching key, *tok_len the
 * number's length. */
long hf_json_nonint_field(const char *text, size_t len, const char *const *keys, int nkeys,
                          const char **key, size_t *tok_len);
/* "a string", "a number", "an object", ... of v, for messages. */
const char *hf_json_kind(const cJSON *v);

#endif
