"""The default detector, ``contrast``: particles as local, transient excess of light.

Backscatter is light that a small particle sends back from the lamp: a compact
spot brighter than what is behind it, moving against a scene that changes
slowly.  The detector therefore finds pixels brighter than a *background
estimate* by more than a multiple of the *local noise*, instead of above a
global level:

1. ``downsample`` -- one pass over the frame: for frames 640 px wide or more a
   2x2 area average (a matched filter for spots of 1 px radius and more, halving
   the noise and the work of every later stage), and one channel (for BGR the
   luma, as the camera's Y plane: a whitish particle adds to all three colours
   while their noise averages; the Y plane or a grey frame is used as it is).
2. ``background`` -- the background at a coarse scale (cells of ``cell`` pixels):
   the 3x3-cell median of the cell means ignores a particle filling a cell, so
   uneven lamp cones and dim far scenes are followed while particles are not;
   where a median over ``texture`` pixels is brighter, that (bright texture
   larger than a particle is background from the first frame), and a single
   frame's particles must outshine the rings of pixels around them (lines,
   edges and larger patches do not: see ``texture``).  When frames
   follow each other (a video or the camera), a per-pixel background learnt over
   about ``memory`` frames -- updated only where no particle was found -- takes
   over, so static texture (seabed pebbles, tank padding) stops looking like
   particles, and it moves with the view when the vehicle moves; ``memory=0``
   keeps the detector single-frame.
3. ``threshold`` -- the noise per coarse cell is the robust spread of
   (frame - background) there (median-filtered over cells so particles do not
   inflate it); a pixel is a particle candidate when it exceeds the background
   by ``k`` times that noise and by at least ``min_contrast`` grey levels.
4. ``label`` -- one connected-components pass on the candidate mask; statistics
   from its few non-zero pixels (vectorised, no per-pixel Python).
5. ``measure`` -- split a component where it holds separate intensity peaks
   (touching or overlapping particles), reject what is not a particle (see
   below), and give each particle its brightness-weighted centre, a radius
   reaching its half-maximum extent (``core``) plus ``halo`` pixels of blur, and
   for its score the light it sends back: its excess summed over its pixels
   (see :func:`measure`).

Rejection rule: a component is not a particle when its covering radius exceeds
``max_radius`` (pixels; scaled up for frames wider than 800 px, whose pixels
see less of the scene): a region that large and brighter than its surroundings is lit scene,
not backscatter (a 1 cm bubble 0.3 m from the lens is about 11 px at 800 px).

The modules, in the order a frame meets them:

- ``params``: :class:`ContrastParams`, the settings, and ``CHANNELS``.
- ``working``: stage 1 -- :func:`downsample` to the working image, and the lamp's light map
  brought to it.
- ``background``: stages 2-3 from a single frame -- :func:`spatial_background`, the prominence
  test (:func:`prominence_level`, :func:`prominent_only`) and :func:`threshold_mask`.
- ``model``: stage 2 across frames -- :class:`BackgroundModel`, the learnt per-pixel background
  and noise; ``follow``: its :class:`~.follow.ViewFollowing`, which keeps it on a moving view.
- ``components``: stages 4-5 -- :func:`label` and :func:`measure`; ``split``: the split of
  components holding several particles; ``groups``: per-label reductions both use.
- ``chain``: :func:`build_contrast`, the stages as the runtime times them, and
  :class:`~.chain.ChainState`, what they pass between them and across frames; ``bands``: the
  :class:`~.bands.BandPool` its frame-wide filters run on with ``threads`` > 1.

The measured history of the defaults: ``docs/decisions/001-contrast-tuning.md``.
"""

from __future__ import annotations

from .. import register_detector
# every name the former single module offered (tests import some private helpers).  A monkeypatch
# must target the module that uses a name (chain.downsample, split._bounds), not this package.
from .background import NOISE_WINDOW, noise_at, prominence_level, prominent_only, spatial_background  # noqa: F401
from .background import threshold_mask
from .chain import ChainState, build_contrast  # noqa: F401
from .components import Components, label, measure  # noqa: F401
from .follow import MAX_FOLLOW, PLAIN, ViewFollowing, _profile_shift  # noqa: F401
from .groups import _group_max  # noqa: F401
from .model import BackgroundModel
from .params import CHANNELS, ContrastParams
from .split import _FAR, _bounds, _nearest_peak, _separate, _spots  # noqa: F401
from .working import UNLIT, downsample, to_channel, working_factor  # noqa: F401

__all__ = ["ContrastParams", "CHANNELS", "to_channel", "downsample", "BackgroundModel", "threshold_mask", "label", "measure",
           "build_contrast"]

register_detector("contrast", ContrastParams, build_contrast,
                  "local contrast over a learnt background, threshold in noise units, one labelling pass "
                  "(the default)",
                  sweep=("k", (2.0, 2.5, 3.0, 3.5, 4.0, 5.0, 6.0, 8.0, 10.0, 14.0)), sweep_scaled=("k_expected",),
                  threaded=True)
