#!/usr/bin/env python3
"""A script that takes its first argument for an output folder, --help
included: doc_options.py must report it (docs.options_refused)."""
import os
import sys

os.makedirs(sys.argv[1], exist_ok=True)
