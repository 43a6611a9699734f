"""Puts an experiment into weights/hfnet.py and takes it out again, so that
weights/train.py and weights/experiments/eval_rows.py build and run networks
no backend knows without a copy of either: install replaces hfnet's
attributes by name and gives every Kernel configuration the experiment's
entries; uninstall restores what hfnet had when this module was imported."""
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
import hfnet  # noqa: E402

ORIGINAL = {name: getattr(hfnet, name) for name in ("HairNet", "kernel_finish", "variant_config")}


def install(kernel_entries, **attributes):
    """Sets each of hfnet's `attributes` (a name of ORIGINAL each) and makes
    hfnet.variant_config(name) return, for the Kernel architecture, its
    configuration updated with kernel_entries(cfg) (a dict)."""
    unknown = set(attributes) - set(ORIGINAL)
    if unknown:
        raise ValueError(f"not an attribute an experiment replaces: {', '.join(sorted(unknown))}")

    def config(name):
        cfg = ORIGINAL["variant_config"](name)
        if cfg["arch"] == "kernel":
            cfg.update(kernel_entries(cfg))
        return cfg

    for name, value in attributes.items():
        setattr(hfnet, name, value)
    hfnet.variant_config = config


def uninstall():
    """Gives hfnet back its own network, Kernel stage and configurations."""
    for name, value in ORIGINAL.items():
        setattr(hfnet, name, value)


def init_or_train(command, args, start_from_kernel):
    """The `init` and `train` commands of an experiment, its stage already
    installed. init: args = OUT [KERNEL], writes start_from_kernel(cfg,
    state) of KERNEL (default weights/kernel.safetensors) to OUT; train:
    args are weights/train.py's. Returns the exit status."""
    if command == "init":
        src = args[1] if len(args) > 1 else os.path.join(os.path.dirname(os.path.abspath(__file__)),
                                                         "..", "kernel.safetensors")
        cfg, state = start_from_kernel(*hfnet.load_safetensors(src))
        hfnet.save_safetensors(args[0], cfg, state)
        return 0
    import train
    return train.main(args)
