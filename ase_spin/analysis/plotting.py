"""Pictures of spectra: S(q, E) as an intensity map over a q path, with spin-wave
bands drawn over it (needs matplotlib)."""

from __future__ import annotations

import numpy as np

__all__ = ["plot_spectrum"]


def _axes(ax):
    if ax is not None:
        return ax
    try:
        from matplotlib.figure import Figure
    except ImportError:
        raise ImportError("pictures need matplotlib: pip install 'ase-spin[plot]' "
                          "(or pip install matplotlib)") from None
    return Figure(figsize=(7.0, 4.5), layout="constrained").add_subplot()


def _columns(x, start, end):
    """Left and right edges of a column around each q: half-way to the nearest
    other abscissa on each side, the path's ends (``start``, ``end``) beyond
    the first and last (the columns tile the path)."""
    x = np.asarray(x, dtype=float)
    distinct = np.unique(x)
    left = np.empty_like(x)
    right = np.empty_like(x)
    for k, xk in enumerate(x):
        below = distinct[distinct < xk]
        above = distinct[distinct > xk]
        left[k] = 0.5 * (xk + below[-1]) if len(below) else min(start, xk)
        right[k] = 0.5 * (xk + above[0]) if len(above) else max(end, xk)
    return left, right


def plot_spectrum(spectrum, ax=None, bands=None, component="transverse", max_meV=None,
                  log=True, cmap="viridis", band_style=None):
    """S(q, E) of a :class:`~ase_spin.analysis.spectra.Spectrum` as an intensity
    map: the q path across (high-symmetry points marked), E = ħω (meV) up;
    ``bands`` (a :class:`~ase_spin.analysis.lswt.MagnonBands` on a path of the
    same crystal) drawn over it. ``component``: "transverse" (default),
    "longitudinal", "plus", "minus" or "total". ``max_meV``: the top of the
    energy axis (default: the highest band, or the highest energy).
    ``log``: a logarithmic colour scale over three decades. Returns the Axes
    (a new figure's without ``ax``: ``ax.figure.savefig(...)``)."""
    from matplotlib.colors import LogNorm, Normalize

    ax = _axes(ax)
    s = spectrum.component(component)
    e = spectrum.energy_meV
    keep = e >= -0.5 * spectrum.resolution_meV
    e, s = e[keep], s[:, keep]
    top = float(s.max()) if s.size and s.max() > 0 else 1.0
    norm = LogNorm(vmin=top * 1e-3, vmax=top) if log else Normalize(vmin=0.0, vmax=top)
    edges_e = np.concatenate([e - 0.5 * spectrum.resolution_meV,
                              [e[-1] + 0.5 * spectrum.resolution_meV]])
    path = bands.qpath if bands is not None and bands.qpath.special else spectrum.qpath
    xs, names = path.labels()
    left, right = _columns(spectrum.qpath.x, min(xs, default=np.inf),
                           max(xs, default=-np.inf))
    mesh = None
    for k in range(len(s)):
        column = np.clip(s[k][:, None], top * 1e-3 if log else 0.0, None)
        mesh = ax.pcolormesh([left[k], right[k]], edges_e, column, norm=norm, cmap=cmap,
                             shading="flat", rasterized=True)
    if mesh is not None:
        ax.figure.colorbar(mesh, ax=ax, label=f"S(q, E), {component} (1/meV per spin)")
    if bands is not None:
        style = {"color": "w", "lw": 1.0, "ls": "--", "alpha": 0.9}
        style.update(band_style or {})
        for n in range(bands.energy_meV.shape[1]):
            ax.plot(bands.qpath.x, bands.energy_meV[:, n], **style,
                    label="linear spin waves" if n == 0 else None)
        ax.legend(loc="upper left", fontsize="small")
    if max_meV is None:
        max_meV = float(np.max(bands.energy_meV)) * 1.15 if bands is not None else e[-1]
    ax.set_ylim(0.0, max_meV)
    for x in xs:
        ax.axvline(x, color="0.7", lw=0.6)
    if xs:
        ax.set_xticks(xs, names)
    ax.set_xlim(left.min(), right.max())
    ax.set_xlabel("wave vector q")
    ax.set_ylabel("E = ħω (meV)")
    return ax
