"""Matcher backends behind one interface, with an explicit registry.

    from densecalib_ros.core.method.matching import create_matcher, available_matchers
    matcher = create_matcher("sift", max_image_side_px=1024)
    matcher.load()
    match_set = matcher.match(images)   # core.types.SiteMatchSet

Backends are imported lazily by name, so importing this package (or using `sift`) imports no torch.
"""
from __future__ import annotations

import importlib
import inspect

from ...errors import InputError
from .base import Matcher

# name -> (module in this package, class). Explicit on purpose: no discovery by introspection.
_REGISTRY: dict[str, tuple[str, str]] = {
    "sift": (".sift", "SiftMatcher"),
    "asift": (".sift", "AsiftMatcher"),
    "xfeat-lighterglue": (".xfeat_lighterglue", "XFeatLighterGlueMatcher"),
    "xfeat-star": (".xfeat_star", "XFeatStarMatcher"),
    "roma": (".roma", "RomaMatcher"),
}


def available_matchers() -> list[str]:
    """Names accepted by `create_matcher`."""
    return list(_REGISTRY)


def matcher_class(name: str) -> type[Matcher]:
    """The backend class registered under `name` (imports its module)."""
    if name not in _REGISTRY:
        raise InputError(f"Unknown matcher {name!r}: choose one of {', '.join(_REGISTRY)}.")
    module, cls = _REGISTRY[name]
    return getattr(importlib.import_module(module, __name__), cls)


def create_matcher(name: str, **options) -> Matcher:
    """Build the backend `name` with its options (no weights are loaded: call `load()`).

    Unknown names or options raise InputError listing the valid ones.
    """
    cls = matcher_class(name)
    valid = [p for p in inspect.signature(cls.__init__).parameters if p != "self"]
    unknown = sorted(set(options) - set(valid))
    if unknown:
        raise InputError(f"Unknown option(s) {', '.join(unknown)} for matcher {name!r}: "
                         f"valid options are {', '.join(valid)}.")
    return cls(**options)


__all__ = ["Matcher", "available_matchers", "create_matcher", "matcher_class"]
