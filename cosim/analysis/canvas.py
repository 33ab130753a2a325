"""How cosim's figures look, and the canvas a figure is drawn on (``cosim.analysis.plot`` draws them).

Two styles:

- ``screen`` (the default): 9 in wide, each figure titled, legends naming an estimator's kind beside
  its name where it says more;
- ``paper``: the width of a column, 3.5 in (``single``, IEEE's) or 7.16 in (``double``, both
  columns), 8 pt text, thin lines, legends with the names the scenario gave.

Either may be given another width. PDFs embed their fonts as TrueType (Type 42, which journals'
checks accept, unlike Type 3); SVGs keep text as text. Every series (an estimator, a sensor, a
residual component) has a look of its own: a colour of the Okabe–Ito palette (told apart with each
common colour-vision deficiency), a dash pattern and an open marker, the markers about every eighth
of a curve and staggered from one series to the next, so that seven series stay apart in grey print
and where curves lie on each other (two schemes that agree). An estimator keeps its look in every
figure. Reference curves (the truth) are wide and light grey, under the curves compared with them.
Legends sit outside the data: under the figure, or above a panel whose curves are its own.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from cosim.analysis.series import RunSeries, first_tick

if TYPE_CHECKING:
    from matplotlib.artist import Artist
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure
    from matplotlib.legend import Legend

#: Figure formats and what matplotlib writes into them that would change from one run to the next.
FORMATS = {"png": {"Software": None}, "svg": {"Date": None}, "pdf": {"CreationDate": None}}
#: Column widths (in) of a two-column paper (IEEE).
WIDTHS = {"single": 3.5, "double": 7.16}
DECADES = 6  # a log axis shows this many decades below its largest value
GAP = 3  # a curve is broken where more ticks than this are missing
TIME = "time t [s]"
#: The legend's name of the shaded windows of the faults, and their colour (grey, 6 % opaque).
SHADED = "fault active"
SHADE = (0.5, 0.5, 0.5, 0.06)
#: A paper's title is made smaller down to this size (pt) before it is allowed a second line.
SMALLEST_TITLE = 6.5

#: Okabe & Ito (2008), "Color Universal Design": apart for protan, deutan and tritan vision (black,
#: the eighth, is left to the truth and the events).
PALETTE = ("#0072B2", "#D55E00", "#009E73", "#CC79A7", "#E69F00", "#56B4E9", "#F0E442")
#: Solid, dashed, dotted, dash-dot, short dashes, dash-dot-dot, long-short dashes (in line widths).
DASHES: tuple[Any, ...] = (
    "-",
    (0, (5.0, 1.6)),
    (0, (1.0, 1.4)),
    (0, (6.0, 1.6, 1.0, 1.6)),
    (0, (2.6, 1.3)),
    (0, (8.0, 1.6, 1.0, 1.6, 1.0, 1.6)),
    (0, (7.0, 1.6, 2.6, 1.6)),
)
MARKERS = ("o", "s", "^", "D", "v", "<", "p")

_COMMON: dict[str, Any] = {
    "svg.fonttype": "none",  # text stays text
    "pdf.fonttype": 42,  # fonts embedded as TrueType
    "ps.fonttype": 42,
    "axes.formatter.useoffset": False,  # tick labels say their values (|Γ| near 1.0003 is not "+1")
    "legend.handlelength": 3.2,  # long enough to show a dash pattern around its marker
    "legend.numpoints": 1,
}


@dataclass(frozen=True)
class Style:
    """How large a figure is and how its text and lines are drawn."""

    name: str
    width: float
    """inches"""
    scale: float
    """panel heights relative to the screen's"""
    line: float
    """curve width (pt)"""
    marker: float
    """marker size (pt)"""
    kinds: bool
    """legends name an estimator's kind beside its name"""
    rc: Any
    """matplotlib's rc parameters (typed by matplotlib as its literal keys)"""

    @classmethod
    def of(cls, name: str = "screen", width: str | float | None = None) -> Style:
        """The style ``name`` (screen, paper) at ``width`` (single, double or inches; default its own)."""
        inches = WIDTHS[width] if isinstance(width, str) else width
        if name == "paper":
            return cls("paper", inches or WIDTHS["single"], 0.62, 0.9, 3.2, False, {**_COMMON, **_PAPER})
        return cls("screen", inches or 9.0, 1.0, 1.1, 4.5, True, {**_COMMON, **_SCREEN})


_SCREEN = {
    "axes.titlesize": 10,
    "axes.labelsize": 9,
    "figure.labelsize": 9,
    "xtick.labelsize": 8,
    "ytick.labelsize": 8,
    "legend.fontsize": 7.5,
    "figure.titlesize": 11,
}
_PAPER = {
    "font.size": 8,
    "legend.frameon": False,
    "axes.titlesize": 8,
    "axes.labelsize": 8,
    "figure.labelsize": 8,
    "xtick.labelsize": 7,
    "ytick.labelsize": 7,
    "legend.fontsize": 7,
    "figure.titlesize": 8,
    "axes.linewidth": 0.6,
    "grid.linewidth": 0.4,
    "xtick.major.width": 0.6,
    "ytick.major.width": 0.6,
    "xtick.major.size": 2.5,
    "ytick.major.size": 2.5,
    "legend.columnspacing": 1.2,
    "legend.handletextpad": 0.5,
    "legend.borderaxespad": 0.2,
    "figure.constrained_layout.h_pad": 0.03,
    "figure.constrained_layout.w_pad": 0.03,
}


class Canvas:
    """One log's figures in the making: its series, the style, a look per estimator, the files written."""

    def __init__(self, series: RunSeries, out: Path, fmt: str, dpi: int, style: Style, title: bool = True) -> None:
        import matplotlib.pyplot as plt

        self.plt, self.series, self.out, self.fmt, self.dpi = plt, series, out, fmt, dpi
        self.style, self.title = style, title
        self.index = {name: i for i, name in enumerate(series.estimators)}
        self.end = max(series.truth, default=0) * series.sample_time
        self.written: list[Path] = []

    @cached_property
    def truth(self) -> tuple[np.ndarray, np.ndarray]:
        """(t, x): the true state at every tick."""
        s = self.series
        ks = np.array(sorted(s.truth), dtype=int)
        return ks * s.sample_time, np.array([s.truth[k] for k in ks]).reshape(len(ks), len(s.states))

    @cached_property
    def reconfigured_at(self) -> float | None:
        """When the controller reconfigured (s), or None."""
        s = self.series
        if s.reconfigured and (k := first_tick(s.control, s.reconfigured[0])) is not None:
            return k * s.sample_time
        return None

    def label(self, name: str) -> str:
        """An estimator in a legend: the name the scenario gave it, and on screen its kind where that
        says more (the name its class declares, for a plugin given by its module path)."""
        kind = self.series.estimators[name].shown_kind
        return name if not self.style.kinds or kind == name else f"{name} ({kind})"

    # -- curves -----------------------------------------------------------------------------------

    def look(self, i: int, points: int) -> dict[str, Any]:
        """The look of the i-th series of a figure, for a curve of ``points`` points."""
        every = max(1, points // 8)
        return {
            "color": PALETTE[i % len(PALETTE)],
            "ls": DASHES[(i + i // len(PALETTE)) % len(DASHES)],
            "marker": MARKERS[(i + 3 * (i // len(PALETTE))) % len(MARKERS)],
            "markevery": ((i % len(PALETTE)) * every // len(PALETTE), every),
            "ms": self.style.marker,
            "mfc": "white",
            "mew": 0.7 * self.style.line,
            "lw": self.style.line,
        }

    def curve(
        self,
        ax: Axes,
        t: np.ndarray,
        v: np.ndarray,
        i: int,
        label: str | None,
        log: bool = False,
        along: np.ndarray | None = None,
    ) -> None:
        """The i-th series of a panel, in its look, broken where its values are missing for more
        than ``GAP`` ticks (an estimator's frames that did not arrive: no line is drawn across);
        its markers again above every curve, so that curves drawn later over it do not hide which
        it is. ``along``: the times of the values, where ``t`` is not time (a path in the plane)."""
        t, v = gapped(t, v, t if along is None else along, GAP * self.series.sample_time)
        look = self.look(i, len(t))
        (ax.semilogy if log else ax.plot)(t, v, label=label, **look)
        marks = ("color", "marker", "markevery", "ms", "mfc", "mew")
        ax.plot(t, v, ls="none", zorder=2.6, **{key: look[key] for key in marks})

    def estimator(
        self, ax: Axes, name: str, t: np.ndarray, v: np.ndarray, log: bool = False, along: np.ndarray | None = None
    ) -> None:
        """An estimator's curve, in its look (the same in every figure), named by ``label``."""
        self.curve(ax, t, v, self.index[name], self.label(name), log, along)

    def reference(self, ax: Axes, t: np.ndarray, v: np.ndarray, label: str) -> None:
        """A true value, wide and light, under the curves compared with it."""
        ax.plot(t, v, color="0.62", lw=2.6 * self.style.line, solid_capstyle="butt", zorder=1.5, label=label)

    # -- the figure -------------------------------------------------------------------------------

    def figure(self, rows: int, columns: int = 1, height: float = 2.2, **kw: Any) -> tuple[Figure, np.ndarray]:
        """Panels of ``height`` (screen inches, scaled to the style) in rows and columns."""
        s = self.style
        around = 0.6 if s.name == "screen" else 0.95  # title, time axis and legend: a paper's text is not smaller
        tall = max(2.8 * s.scale, height * s.scale * rows + around)
        return self.plt.subplots(rows, columns, figsize=(s.width, tall), squeeze=False, layout="constrained", **kw)

    def save(self, fig: Figure, name: str, heading: str) -> None:
        """Written with its title; a paper's figure exactly as wide as its column (its layout keeps
        everything inside), a screen's to its drawn extent."""
        if self.title:
            self.titled(fig, f"{self.series.scenario}: {heading}", heading)
        target = self.out / f"{name}.{self.fmt}"
        tight: dict[str, Any] = {"bbox_inches": "tight", "pad_inches": 0.08} if self.style.name == "screen" else {}
        fig.savefig(target, dpi=self.dpi, metadata=FORMATS[self.fmt], **tight)
        self.plt.close(fig)
        self.written.append(target)

    def titled(self, fig: Figure, full: str, short: str) -> None:
        """The figure's title: on screen ``full``, wrapped to the width; in a paper on one line, as
        measured: ``full``, else ``short`` (without the scenario's name), else ``short`` in smaller
        type down to ``SMALLEST_TITLE`` (a column is 3.5 in), and only then on two lines."""
        if self.style.name == "screen":
            fig.suptitle(full, wrap=True)
            return
        renderer = fig.canvas.get_renderer()  # type: ignore[attr-defined]
        size = float(self.style.rc["figure.titlesize"])
        sizes = [size - 0.5 * i for i in range(int((size - SMALLEST_TITLE) / 0.5) + 1)]
        for text, points in [(full, size), *((short, p) for p in sizes)]:
            title = fig.suptitle(text, fontsize=points)
            if title.get_window_extent(renderer).width <= 0.98 * fig.bbox.width:
                return
        fig.suptitle(short, fontsize=SMALLEST_TITLE, wrap=True)

    def state_grid(self, names: list[str]) -> tuple[Figure, list[Axes]]:
        """A panel per state, in two columns when there are more than three and room for two."""
        columns = 2 if len(names) > 3 and self.style.width > 6 else 1
        rows = -(-len(names) // columns)
        fig, axes = self.figure(rows, columns, height=2.0, sharex=True)
        cells = list(axes.T.ravel())
        for ax in cells[len(names) :]:
            ax.set_visible(False)
        for ax in axes[-1]:
            ax.set_xlabel(TIME)
        if len(names) % columns:  # the column with one fewer panel gets its time axis labelled too
            cells[len(names) - 1].set_xlabel(TIME)
            cells[len(names) - 1].tick_params(labelbottom=True)
        return fig, cells

    # -- legends ----------------------------------------------------------------------------------

    def fitted(self, fig: Figure, make: Callable[[int], Legend], entries: int, width: float) -> None:
        """The legend ``make(ncol)`` with as many columns as fit in ``width`` inches, its rows
        balanced: measured, not guessed (a legend wider than a paper's figure would be cut)."""
        renderer = fig.canvas.get_renderer()  # type: ignore[attr-defined]
        for ncol in range(entries, 0, -1):
            rows = -(-entries // ncol)
            if ncol > 1 and -(-entries // (ncol - 1)) == rows:
                continue  # as many rows with fewer columns: the balanced layout
            legend = make(ncol)
            if ncol == 1 or legend.get_window_extent(renderer).width <= width * fig.dpi:
                return
            legend.remove()

    def legend(self, fig: Figure, cells: Sequence[Axes], leave: Sequence[str] = ()) -> None:
        """One legend under the panels: each curve's name once (but those of ``leave``), the faults'
        shaded windows too."""
        from matplotlib.patches import Patch

        found: dict[str, Artist] = {}
        for ax in cells:
            for handle, text in zip(*ax.get_legend_handles_labels()):
                if text not in leave:
                    found.setdefault(text, handle)
        if SHADED in found:  # as the windows look, with an edge: a patch as light as they are is not seen
            found[SHADED] = Patch(facecolor=SHADE, edgecolor="0.6", linewidth=0.4 * self.style.line)
            found[SHADED] = found.pop(SHADED)  # last, after the curves and the onsets
        if found:

            def make(ncol: int) -> Legend:
                return fig.legend(list(found.values()), list(found), loc="outside lower center", ncol=ncol)

            self.fitted(fig, make, len(found), 0.98 * self.style.width)

    def legend_above(self, ax: Axes, labels: Sequence[str]) -> None:
        """A panel's own curves (``labels``) named above it."""
        handles = [h for h, text in zip(*ax.get_legend_handles_labels()) if text in labels]

        def make(ncol: int) -> Legend:
            return ax.legend(handles=handles, loc="lower left", bbox_to_anchor=(0.0, 1.0), ncol=ncol, frameon=False)

        # from the panel's left edge to the figure's (a y axis's labels to the left of it)
        self.fitted(ax.figure, make, len(handles), self.style.width - 0.85)  # type: ignore[arg-type]

    def finish(self, ax: Axes, ylabel: str) -> None:
        """The panel's y label (on two lines, before its parenthesis, where one line would run past
        a panel's height: ``|x − x̂|`` over ``(mixes m, rad, m/s, rad/s)``) and its grid."""
        if len(ylabel) > 30 * self.style.scale and " (" in ylabel:
            head, tail = ylabel.split(" (", 1)
            ylabel = f"{head}\n({tail}"
        ax.set_ylabel(ylabel)
        ax.grid(alpha=0.3)

    def finish_column(self, fig: Figure, axes: np.ndarray, name: str, heading: str, leave: Sequence[str] = ()) -> None:
        """A column of panels over time (``figure``'s axes): the time axis named under the last, one
        legend under them all (but the curves of ``leave``), saved as ``name``."""
        axes[-1, 0].set_xlabel(TIME)
        self.legend(fig, list(axes[:, 0]), leave)
        self.save(fig, name, heading)

    def finish_pair(
        self, fig: Figure, axes: tuple[Axes, Axes], ylabels: tuple[str, str], name: str, heading: str
    ) -> None:
        """A figure of two panels over time, the values above, their error (log scale) below: the
        faults shaded in both and named above, the labels, the legend, saved as ``name``."""
        upper, lower = axes
        for ax in axes:
            self.faults_shaded(ax)
        self.onsets_named(upper)
        self.finish(upper, ylabels[0])
        self.finish(lower, ylabels[1])
        lower.set_xlabel(TIME)
        self.legend(fig, [upper, lower])
        self.save(fig, name, heading)

    # -- faults and events ------------------------------------------------------------------------

    def faults_shaded(self, ax: Axes) -> None:
        """Every fault's window shaded (in the legend once: "fault active"), its onset dotted (in
        the legend once: "fault onset")."""
        for f in self.series.faults:
            stop = self.end if f.get("end") is None else f["end"]
            ax.axvspan(f["start"], stop, facecolor=SHADE, lw=0, label=SHADED)
        self.onsets(ax)

    def onsets(self, ax: Axes) -> None:
        for f in self.series.faults:
            ax.axvline(f["start"], color="0.35", ls=":", lw=0.9 * self.style.line, label="fault onset")

    def onsets_named(self, ax: Axes) -> None:
        """Each fault's name (the scenario's) at its onset, at the top of ``ax``; faults that start
        together in one mark."""
        starts: dict[float, list[str]] = {}
        for f in self.series.faults:
            starts.setdefault(f["start"], []).append(f["label"])
        size = 6.5 if self.style.name == "screen" else 5.5
        for start, names in starts.items():
            ax.annotate(
                f" {', '.join(names)}",
                (start, 1),
                xycoords=("data", "axes fraction"),
                xytext=(-1.5, 0),
                textcoords="offset points",
                rotation=90,
                va="top",
                ha="right",
                fontsize=size,
                color="0.3",
            )

    def events(self, ax: Axes, isolations: Sequence[tuple[float, str]] = ()) -> None:
        """Fault onsets (grey, dotted), isolations (named, dashed) and the reconfiguration (dash-dot)."""
        self.onsets(ax)
        lw = 1.1 * self.style.line
        for t, what in isolations:  # in black, apart from the series' colours by their dashes
            ax.axvline(t, color="k", ls=(0, (4, 2)), lw=lw, label=f"isolated {what} at {t:g} s")
        if (at := self.reconfigured_at) is not None:
            ax.axvline(at, color="k", ls=(0, (6, 2, 1, 2)), lw=lw, label=f"reconfigured at {at:g} s")


def gapped(x: np.ndarray, y: np.ndarray, times: np.ndarray, gap: float) -> tuple[np.ndarray, np.ndarray]:
    """(x, y) with a NaN wherever ``times`` (those of the points) jump by more than ``gap``:
    matplotlib draws no line across it."""
    cut = np.flatnonzero(np.diff(times) > gap) + 1
    if not cut.size:
        return x, y
    return np.insert(np.asarray(x, dtype=float), cut, np.nan), np.insert(np.asarray(y, dtype=float), cut, np.nan)


def log_floor(ax: Axes, curves: Sequence[np.ndarray]) -> None:
    """A log axis that spans ``DECADES`` below the largest value (not down to a curve's zeros)."""
    top = max((float(np.max(v)) for v in curves if np.size(v)), default=0.0)
    if top > 0:
        ax.set_ylim(top * 10.0**-DECADES, top * 2.0)
    else:  # nothing above zero (a fault rejected exactly): an axis of its own, not matplotlib's complaint
        ax.set_ylim(10.0**-DECADES, 1.0)


def log_scale(ax: Axes, curves: Sequence[np.ndarray]) -> str:
    """A log axis for ``curves`` (drawn on a linear one), ``DECADES`` below the largest value; where
    a curve is zero for a while (|h_Γ| before the fault), a log axis would leave those values out
    and draw the curve from nowhere: a symmetric log axis instead, linear below the smallest decade
    it shows, with 0 at its foot. Returns what the axis's label says of its scale."""
    values = [v[np.isfinite(v)] for v in (np.asarray(c, dtype=float) for c in curves)]
    top = max((float(v.max()) for v in values if v.size), default=0.0)
    if top <= 0:  # nothing above zero: a linear axis says it best
        return ""
    floor = top * 10.0**-DECADES
    if not any((v <= 0).any() for v in values):
        ax.set_yscale("log")
        ax.set_ylim(floor, top * 2.0)
        return " (log scale)"
    smallest = min(float(v[v > 0].min()) for v in values if (v > 0).any())
    decade = int(np.floor(np.log10(max(floor, smallest))))
    ax.set_yscale("symlog", linthresh=10.0**decade, linscale=0.5)
    ax.set_ylim(0.0, top * 2.0)
    return f" (log scale, linear below 1e{decade})"
