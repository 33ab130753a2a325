"""The ranking of a leaderboard's groups: chains of schemes compared neighbour by neighbour, their
ranks once the comparisons are judged, and each benchmark track's mean ranks.

A group's estimators form one chain, ranked by their median error and compared by their errors;
the schemes that only diagnose form another, ranked by their diagnosis and compared by it; a
scheme with neither has no rank. The comparisons of every chain of the board are judged together
(``cosim.campaign.verdicts``: Holm over the board); where a separated comparison shows the next
scheme better than the one ranked above it (a median can rank them one way while the runs, pair
by pair, show the other), the two are swapped and the board judged again.
"""

from __future__ import annotations

import math
from collections import defaultdict
from typing import TYPE_CHECKING, Any

from cosim.campaign.verdicts import NOT_SEPARATED, SEPARATED, TIED, judge, paired_comparison, sign_comparison

if TYPE_CHECKING:
    from cosim.campaign.scores import Entry

Chain = list[tuple[dict[str, Any], "Entry"]]
"""Schemes in ranked order, each with its scores (``vs_next``: its comparison with the next)."""


def chains(entries: dict[tuple[str, str], Entry]) -> tuple[Chain, Chain, Chain]:
    """A group's schemes ranked (``rank_key``): the estimators, compared by their errors; then the
    schemes that only diagnose, compared by their diagnoses; then any scheme with neither (nothing
    to compare it by: no rank)."""
    scored = sorted(((entry.scores(), entry) for entry in entries.values()), key=lambda pair: rank_key(pair[0]))
    estimation = [pair for pair in scored if pair[1].rms_by_run]
    diagnosis = [pair for pair in scored if not pair[1].rms_by_run and pair[1].diagnoses]
    rest = [pair for pair in scored if not pair[1].rms_by_run and not pair[1].diagnoses]
    for chain, measure in ((estimation, "estimation"), (diagnosis, "diagnosis"), (rest, None)):
        for score, _ in chain:
            score["chain"] = measure
    return estimation, diagnosis, rest


def compare(chain: Chain, margin: float) -> None:
    """Compare each scheme of a chain with the next on their common runs."""
    for (score, entry), (_, following) in zip(chain, chain[1:]):
        comparison = (
            paired_comparison(entry.rms_by_run, following.rms_by_run, margin)
            if score["chain"] == "estimation"
            else sign_comparison(entry.diagnosis_by_run, following.diagnosis_by_run, margin)
        )
        score["vs_next"] = comparison | {"estimator": following.estimator}
    if chain:
        chain[-1][0].pop("vs_next", None)


def _reversed(chain: Chain) -> int | None:
    """Where a chain ranks a scheme above the next though their runs show the next better (ranked by
    its median error, it can be worse run by run): the first such place."""
    for i, (score, _) in enumerate(chain[:-1]):
        c = score["vs_next"]
        if c["verdict"] == SEPARATED and (c["better"] > c["worse"] if c["measure"] == "diagnosis" else c["ratio"] < 1):
            return i
    return None


def judged(chains: dict[Any, tuple[Chain, Chain, Chain]], margin: float) -> dict[str, Any]:
    """Compare the schemes of every chain, judge the comparisons over the whole board, and swap any
    two a separated comparison shows in the wrong order (then judge again): no scheme ranks above
    one its runs show better."""
    every = [chain for found in chains.values() for chain in found[:2]]
    for chain in every:
        compare(chain, margin)
    for _ in range(1 + sum(len(chain) ** 2 for chain in every)):
        verdicts = judge([score["vs_next"] for chain in every for score, _ in chain if "vs_next" in score], margin)
        swaps = [(chain, i) for chain in every if (i := _reversed(chain)) is not None]
        if not swaps:
            break
        for chain, i in swaps:
            chain[i], chain[i + 1] = chain[i + 1], chain[i]
            compare(chain, margin)
    return verdicts


def place(ranking: list[dict[str, Any]]) -> None:
    """Rank each chain of a group (estimators, then schemes that only diagnose) once its comparisons
    have their verdicts: a scheme's rank is 1 + the number of schemes above it in its chain with a
    separated comparison between (``tied`` and ``not separated`` share a rank); its place is
    ``settled`` where no comparison that places it (those of the schemes sharing its rank, and its
    own) is ``not separated``. A scheme alone in its chain has nothing that places it."""
    for measure in ("estimation", "diagnosis"):
        chain = [s for s in ranking if s["chain"] == measure]
        links = [s["vs_next"]["verdict"] for s in chain[:-1]]
        start = 0
        for i, score in enumerate(chain):
            if i and links[i - 1] == SEPARATED:
                start = i
            score["rank"] = start + 1
            near = links[max(0, i - 1) : i + 1]
            score["tied"] = TIED in near
            score["shared"] = any(link != SEPARATED for link in near)
        i = 0
        while i < len(chain):
            j = i
            while j < len(links) and links[j] != SEPARATED:
                j += 1
            settled = len(chain) > 1 and NOT_SEPARATED not in links[i:j]
            for score in chain[i : j + 1]:
                score["settled"] = settled
            i = j + 1
    for score in ranking:
        if score["chain"] is None:
            score |= {"rank": None, "tied": False, "shared": False, "settled": False}


def track_ranks(groups: list[dict[str, Any]]) -> dict[str, list[dict[str, Any]]]:
    """Per track, each scheme's mean rank over the cases where its place is settled (as diagnosis
    competitions rank across their test cases; a case whose comparisons could not place it is
    counted apart), best first; the schemes never placed last."""
    places: dict[str, dict[tuple[str, str], list[int | None]]] = defaultdict(lambda: defaultdict(list))
    names: dict[tuple[str, str], str] = {}
    for group in groups:
        track = str(group["group"].get("track"))
        for score in group["ranking"]:
            places[track][(score["estimator"], score["kind"])].append(score["rank"] if score["settled"] else None)
            names[(score["estimator"], score["kind"])] = score["kind_name"]
    out = {}
    for track, by_scheme in sorted(places.items()):
        schemes: list[dict[str, Any]] = []
        for (name, kind), ranks in by_scheme.items():
            placed = [rank for rank in ranks if rank is not None]
            mean = sum(placed) / len(placed) if placed else None
            schemes.append(
                {
                    "estimator": name,
                    "kind": kind,
                    "kind_name": names[(name, kind)],
                    "mean_rank": mean,
                    "cases": len(ranks),
                    "placed": len(placed),
                }
            )
        out[track] = sorted(
            schemes, key=lambda s: (s["mean_rank"] is None, s["mean_rank"] or 0.0, -s["placed"], s["estimator"])
        )
    return out


def rank_key(score: dict[str, Any]) -> tuple[float, ...]:
    """Estimators by their error; schemes that only diagnose after them, by detection rate, false
    alarms, isolation accuracy and detection delay."""
    inf = math.inf

    def value(key: str, sign: float = 1.0) -> float:
        found = score.get(key)
        return inf if found is None else sign * found

    return (
        value("rms_post_fault_median"),
        value("detection_rate", -1.0),
        value("false_alarms_per_hour"),
        value("isolation_accuracy", -1.0),
        value("detection_delay_median_s"),
    )
