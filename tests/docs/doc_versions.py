#!/usr/bin/env python3
"""The client READMEs say which protocol version their client speaks in
their opening paragraph; that version must be the newest one the codec
speaks (HFP_VERSION in protocol/hfproto.h), so that a version bump does not
leave them naming an older one.

usage: doc_versions.py SOURCE_DIR"""
import re
import sys

PAGES = ["client/lib/README.md", "client/python/README.md"]
# "speaks protocol v3", "(protocol/PROTOCOL.md, version 3, ..."
CLAIM = re.compile(r"speaks\s+protocol\s+v(\d+)|PROTOCOL\.md(?:\]\([^)]*\))?,\s+version\s+(\d+)")


def main():
    root = sys.argv[1]
    with open(root + "/protocol/hfproto.h") as f:
        m = re.search(r"#define\s+HFP_VERSION\s+(\d+)", f.read())
    if not m:
        sys.exit("doc_versions: no HFP_VERSION in protocol/hfproto.h")
    newest = int(m.group(1))
    bad = 0
    for page in PAGES:
        with open(root + "/" + page) as f:
            text = f.read()
        # the opening paragraph: after the title, up to the first blank line
        intro = text.split("\n\n")[1]
        claim = CLAIM.search(intro)
        if not claim:
            print("%s: its opening paragraph does not say which protocol version the client "
                  "speaks" % page)
            bad += 1
            continue
        said = int(claim.group(1) or claim.group(2))
        if said != newest:
            print("%s: says the client speaks protocol version %d; the codec's newest is %d "
                  "(HFP_VERSION): update the page" % (page, said, newest))
            bad += 1
    if bad:
        sys.exit(1)
    print("doc_versions: %d page(s) name protocol version %d" % (len(PAGES), newest))


if __name__ == "__main__":
    main()
