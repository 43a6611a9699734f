/* The variant a load tool was asked for, looked up on the server the way
 * the server matches names. Shared by `hairfilter load` and
 * `hairfilter-load`. */
#ifndef HF_LOAD_VARIANT_H
#define HF_LOAD_VARIANT_H

#include <hairfilter/hairfilter.h>

/* Lists c's variants and fills *found with the one named name, matched
 * without regard to case as the server matches (found->name is the
 * server's spelling). 0 when found; 1, with a line on stderr starting
 * with prog, when listing fails or the server has no such variant (the
 * line names the ones it has). */
int load_find_variant(hfc_client *c, const char *prog, const char *name, hfc_variant *found);

#endif
