"""hairfilter: a Python client of hairfilterd (protocol/PROTOCOL.md).

Pure Python 3 and numpy. See client/python/README.md:

    import hairfilter
    with hairfilter.Client("unix:/run/hairfilterd/hairfilterd.sock") as hf:
        print(hf.info.name, hf.info.software_version, [v.name for v in hf.variants()])
        done = hf.filter("Base", features)     # numpy [h][w][spp*6] -> done.result [h][w][3]
"""

from . import protocol
from .client import Client, Completion, Error, Segment, ServerInfo, Timing

try:
    # Written by the build from project(hairfilter VERSION ...) in CMakeLists.txt.
    from ._version import __version__
except ImportError:   # the bare source tree
    __version__ = "unknown"

__all__ = ["Client", "Completion", "Error", "Segment", "ServerInfo", "Timing", "protocol",
           "__version__"]
