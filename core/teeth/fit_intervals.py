"""What a capture tells about each fitted parameter: an interval, and the combinations it leaves open.

At the fitted scene x the capture's images C(x) change by J d for a parameter displacement d. With per-value
noise variance s^2, the Fisher information of the coefficients t of x + sum_k t_k d_k is F = (J D)^T (J D) / s^2
(the fit's Gauss-Newton matrix in these coordinates, up to the factor 2 / M and the noise), estimated without
bias from independent Monte Carlo passes and pooled over 8 x 8 pixel tiles (``sensitivity.capture_sensitivity``).
No unbiased estimate of a combination v^T t can have a standard deviation below sqrt(v^T F^-1 v) (Cramer-Rao).

The noise s^2 comes from the capture itself, not from a known sample count: in each masked pixel whose four
neighbours are masked too, r = C - (C_left + C_right + C_up + C_down) / 4 has variance s^2 (1 + 1/4) for
independent noise; the robust estimate is (1.4826 median |r - median r|)^2 / 1.25 over all images and channels
(smooth shading adds little to r at a pixel's scale; edges are few and the median ignores them).

Directions (each a step of the fitted value): per volume (enamel, dentin, gums) and colour channel, the
scattering sigma_s and the absorption sigma_a 10 % up (``sensitivity.default_directions``); the phase function's
g1, g2 and beta 0.05 up; every dentin coefficient 0.05 up.

Undetermined: F's eigen-decomposition F = sum w_i v_i v_i^T. A combination v_i with two standard deviations
2 / sqrt(w_i) beyond ``OPEN_STEPS`` steps (or w_i <= 0: below the estimator's own noise) is one the capture
leaves open; the report names its two largest parts in words. A parameter whose squared loading on the open
combinations exceeds ``OPEN_SHARE`` gets no interval (it is named as undetermined); the others get two standard
deviations from the determined combinations, sqrt(sum over determined i of v_ki^2 / w_i).

The similarity relation: light that has scattered a few times through a tissue sees its scattering sigma_s and
its phase function's mean cosine g mostly through the reduced scattering sigma_s (1 - g). Where the capture leaves
a tissue's phase function (g1, g2 or beta) open, the fit can end on another (sigma_s, g) pair far along that
valley, where the local bound above is narrow about the wrong value, and its absorption with it: on a Mitsuba
capture of a forward-scattering truth (``bench teeth-extrapolation``) 21 of 51 parameters had intervals that
missed the truth by 30-230 %, every one a scattering or absorption of a tissue with an open phase function. Such
a tissue's scattering and absorption are reported undetermined, with the trade-off named.
"""

from __future__ import annotations

import numpy as np

from ..errors import UserError
from .capture import Capture
from .param_vector import ParamLayout, scene_to_vector
from .scene import TeethScene
from .sensitivity import capture_sensitivity, default_directions

G_STEP = 0.05  # the phase-function parameters' step (g1, g2, beta are 0..1-ish numbers)
OPEN_STEPS = 5.0  # two standard deviations beyond 5 steps (a 50 % change of sigma_s or sigma_a): not determined
ALONE = 0.3  # an open combination whose second part is below this share of its first: one parameter alone
OPEN_SHARE = 0.1  # a parameter with more than this share of its squared loading on open combinations: no interval


def capture_noise_variance(capture: Capture) -> float:
    """The per-value noise variance of the capture's images, estimated from the images (module docstring)."""
    if capture.images is None or capture.masks is None:
        raise UserError("the capture has no images or masks: its noise cannot be estimated")
    m = capture.masks
    inner = m[:, 1:-1, 1:-1] & m[:, :-2, 1:-1] & m[:, 2:, 1:-1] & m[:, 1:-1, :-2] & m[:, 1:-1, 2:]
    im = capture.images  # (cameras, lights, H, W, 3)
    r = im[:, :, 1:-1, 1:-1] - 0.25 * (im[:, :, :-2, 1:-1] + im[:, :, 2:, 1:-1] + im[:, :, 1:-1, :-2]
                                       + im[:, :, 1:-1, 2:])
    vals = r[np.broadcast_to(inner[:, None, :, :, None], r.shape)]
    if vals.size < 16:
        raise UserError("too few masked pixels with masked neighbours to estimate the capture's noise")
    mad = float(np.median(np.abs(vals - np.median(vals))))
    return (1.4826 * mad) ** 2 / 1.25


def _directions(scene: TeethScene, layout: ParamLayout) -> tuple[list[str], np.ndarray, list[float]]:
    """Names, (K, P) displacements and each one's step in the reported unit (module docstring)."""
    names, rows = default_directions(scene, layout, rel=0.1, dc=G_STEP)
    steps = [0.1 if (".sigma_s[" in n or ".sigma_a[" in n) else G_STEP for n in names]
    rows = list(rows)
    for e in layout.entries:
        if e.kind in ("g", "beta"):
            d = np.zeros(layout.size)
            d[e.start] = G_STEP
            names.append(e.name)
            rows.append(d)
            steps.append(G_STEP)
    return names, np.array(rows), steps


def _value(scene: TeethScene, layout: ParamLayout, name: str) -> float:
    """The fitted value of a direction's parameter: sigma_s, sigma_a from sigma_t and the albedo."""
    x = scene_to_vector(scene, layout)
    if ".sigma_s[" in name or ".sigma_a[" in name:
        prefix, ch = name.split(".sigma_")[0], int(name[-2])
        st, al = x[layout.col(f"{prefix}.sigma_t") + ch], x[layout.col(f"{prefix}.albedo") + ch]
        return float(st * al if ".sigma_s[" in name else st * (1.0 - al))
    if name.endswith("]"):
        base, k = name[:-1].split("[")
        return float(x[layout.col(base) + int(k)])
    return float(x[layout.col(name)])


def _words(name: str) -> str:
    """A parameter's name as an artist reads it: 'tooth0 enamel scattering (red)'."""
    channel = {"0": "red", "1": "green", "2": "blue"}
    for key, text in ((".sigma_s[", "scattering"), (".sigma_a[", "absorption")):
        if key in name:
            owner, ch = name.split(key)[0], name.split(key)[1][0]
            return f"{owner.replace('.', ' ')} {text} ({channel[ch]})"
    for key, text in ((".g1", "forward phase lobe g1"), (".g2", "backward phase lobe g2"),
                      (".beta", "phase lobe mix beta")):
        if name.endswith(key):
            return f"{name[: -len(key)].replace('.', ' ')} {text}"
    if ".c[" in name:
        return f"{name.split('.c[')[0]} dentin shape mode {name.split('.c[')[1][0]}"
    return name


def parameter_intervals(scene: TeethScene, capture: Capture, light_ids: np.ndarray | None = None, passes: int = 4,
                        block: int = 8, seed: int = 7) -> dict:
    """Each parameter's fitted value and 2-standard-deviation interval, and the combinations the capture leaves
    open (module docstring), for ``fit_report.json``. ``light_ids``: the lights the fit used (default all)."""
    if light_ids is not None:
        ids = np.asarray(light_ids, dtype=np.int64)
        capture = Capture(capture.cameras, [capture.lights[i] for i in ids],
                          None if capture.images is None else capture.images[:, ids], capture.masks)
    layout = ParamLayout(scene)
    names, dirs, steps = _directions(scene, layout)
    noise = capture_noise_variance(capture)
    sens = capture_sensitivity(scene, capture, dirs, passes=passes, block=block, noise_variance=noise, seed=seed)
    values = [_value(scene, layout, n) for n in names]
    out = intervals_from_information(sens["information"], names, steps, values)
    out.update({"noise_variance": noise, "passes": passes, "block": block,
                "method": "Cramer-Rao bound from the capture's image Jacobian at the fit (unbiased over independent "
                          "Monte Carlo passes, 8 x 8 tiles), noise estimated from the capture's own pixels "
                          "(core/teeth/fit_intervals.py)"})
    return out


def intervals_from_information(information: np.ndarray, names: list[str], steps: list[float],
                               values: list[float]) -> dict:
    """The intervals and open combinations of the module docstring from the information matrix F of the
    directions (in steps): ``{"parameters": [...], "undetermined": [...], "determined_count": int}``."""
    info = 0.5 * (np.asarray(information, dtype=np.float64) + np.asarray(information, dtype=np.float64).T)
    w, v = np.linalg.eigh(info)
    determined = w > (2.0 / OPEN_STEPS) ** 2
    open_share = (v[:, ~determined] ** 2).sum(axis=1)
    var = (v[:, determined] ** 2 / w[determined]).sum(axis=1)
    params = []
    for k, (n, step, val) in enumerate(zip(names, steps, values, strict=True)):
        relative = ".sigma_s[" in n or ".sigma_a[" in n
        entry = {"name": n, "words": _words(n), "value": float(val), "determined": bool(open_share[k] <= OPEN_SHARE)}
        if entry["determined"]:
            half = 2.0 * float(np.sqrt(var[k])) * step  # relative (sigma_s, sigma_a) or absolute (g, beta, c)
            entry["interval_2sigma"] = [val * (1 - half), val * (1 + half)] if relative else [val - half, val + half]
        else:
            entry["interval_2sigma"] = None
        params.append(entry)
    open_combinations = []
    for i in np.flatnonzero(~determined):
        top = np.argsort(-np.abs(v[:, i]))[:2]
        if len(top) < 2 or abs(v[top[1], i]) < ALONE * abs(v[top[0], i]):  # essentially one parameter
            a = names[top[0]]
            open_combinations.append({
                "parameters": [a], "weights": [float(v[top[0], i])],
                "text": f"{_words(a)} is not measured: changing it changes the photographs less than their noise"})
            continue
        a, b = (names[k] for k in top)
        same = np.sign(v[top[0], i]) == np.sign(v[top[1], i])
        how = "both up or both down" if same else "one up and the other down"
        open_combinations.append({
            "parameters": [a, b], "weights": [float(v[k, i]) for k in top],
            "text": f"{_words(a)} and {_words(b)} trade off ({how} changes the photographs less than their "
                    "noise): only their combination is measured"})
    open_combinations += _similarity_open(params)
    return {"parameters": params, "undetermined": open_combinations,
            "determined_count": int(sum(p["determined"] for p in params))}


def _tissue(name: str) -> str:
    """The tissue a parameter belongs to: ``tooth0.enamel`` of ``tooth0.enamel.sigma_s[0]`` or ``.g1``."""
    for key in (".sigma_s[", ".sigma_a[", ".g1", ".g2", ".beta"):
        if key in name:
            return name.split(key)[0]
    return ""


def _similarity_open(params: list[dict]) -> list[dict]:
    """The similarity relation (module docstring): a tissue whose phase function the capture leaves open has its
    scattering and absorption marked undetermined too (in ``params``, in place); one open combination per such
    tissue, in words."""
    open_phase = {_tissue(p["name"]) for p in params
                  if not p["determined"] and p["name"].endswith((".g1", ".g2", ".beta"))}
    out = []
    for tissue in sorted(open_phase):
        moved = [p for p in params if _tissue(p["name"]) == tissue and p["determined"]
                 and (".sigma_s[" in p["name"] or ".sigma_a[" in p["name"])]
        for p in moved:
            p["determined"], p["interval_2sigma"] = False, None
        words = tissue.replace(".", " ")
        out.append({"parameters": [f"{tissue}.sigma_s", f"{tissue}.g1"], "weights": [],
                    "text": f"{words} scattering and its phase function trade off: the capture measures at most "
                            "their combination, the reduced scattering sigma_s (1 - g), and the absorption only "
                            "together with it (none of them has an interval)"})
    return out


def calibration(report: dict, truth: TeethScene) -> dict:
    """How the intervals of ``report`` (``parameter_intervals``' output for a fit) hold the true values of a
    capture whose truth is known: ``inside_share`` of all parameters (an undetermined one has no interval: not
    inside), and ``outside_determined``, the parameters that have an interval the truth lies outside (each a
    parameter the report should have named as undetermined); per parameter, its truth beside its interval."""
    layout = ParamLayout(truth)
    rows, inside, missed = [], 0, []
    for p in report["parameters"]:
        value = _value(truth, layout, p["name"])
        lo_hi = p["interval_2sigma"]
        hit = lo_hi is not None and min(lo_hi) <= value <= max(lo_hi)
        inside += hit
        if lo_hi is not None and not hit:
            missed.append(p["name"])
        rows.append({"name": p["name"], "truth": value, "fitted": p["value"], "interval_2sigma": lo_hi,
                     "inside": bool(hit)})
    n = len(rows)
    return {"inside_share": inside / n if n else float("nan"), "parameters": n, "inside": int(inside),
            "undetermined": [p["name"] for p in report["parameters"] if p["interval_2sigma"] is None],
            "outside_determined": missed, "per_parameter": rows}


def summary(report: dict, limit: int = 2) -> str:
    """One line for the panel: how many parameters the capture determines, and the first open combinations."""
    n = len(report["parameters"])
    text = f"{report['determined_count']} of {n} parameters determined (2-sigma intervals in fit_report.json)"
    opened = report["undetermined"][:limit]
    if opened:
        text += "; open: " + "; ".join(" with ".join(o["parameters"]) for o in opened)
    return text
