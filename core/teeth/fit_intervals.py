"""What a capture tells about each fitted parameter: an interval, and the combinations it leaves open.

At the fitted scene x the capture's images C(x) change by J d for a parameter displacement d. With per-value
noise variance s^2, the Fisher information of the coefficients t of x + sum_k t_k d_k is F = (J D)^T (J D) / s^2
(the fit's Gauss-Newton matrix in these coordinates, up to the factor 2 / M and the noise), estimated without
bias from independent Monte Carlo passes and pooled over 8 x 8 pixel tiles (``sensitivity.capture_sensitivity``).

The noise s^2 comes from the capture itself, not from a known sample count: in each masked pixel whose four
neighbours are masked too, r = C - (C_left + C_right + C_up + C_down) / 4 has variance s^2 (1 + 1/4) for
independent noise; the robust estimate is (1.4826 median |r - median r|)^2 / 1.25 over all images and channels
(smooth shading adds little to r at a pixel's scale; edges are few and the median ignores them).

Directions (each a step of the fitted value): per volume (enamel, dentin, gums) and colour channel, the
scattering sigma_s and the absorption sigma_a 10 % up (a step of 0.1 in their logarithms,
``sensitivity.default_directions``); the phase function's g1, g2 and beta 0.05 up; every dentin coefficient
0.05 up.

**The fit's own misfit.** Where the fitted scene does not render the capture to within its noise (a model that
is not the photographs' renderer, a stochastic fit short of its minimum), the residual is evidence the noise
alone understates: F is divided by the fit's reduced chi-square b = max(1, chi2 / values) (the Birge ratio,
``sensitivity.capture_sensitivity``'s ``reduced_chi2``). On the Mitsuba captures of ``bench
teeth-extrapolation`` b is 1.4-4.8 (4-13 before ``teeth fit`` clamped their isolated bright values).

**The literature's range as the prior.** F alone has no bound along the combinations the capture leaves open.
The values reported for enamel and dentin span sigma_t 0.3-30 / mm, albedo 0.5-0.999 and g 0.3-0.9 (thesis
Sec. 5.7, ``literature_init``); g2, beta and the dentin coefficients span their valid ranges
(``param_vector.RANGES``); the gums take the teeth's span. Each range, taken as a uniform distribution (log
sigma_t and log10(1 - albedo) uniform, as the literature search samples them), gives a prior covariance
Sigma_0 in the directions' coordinates (with the covariance of log sigma_s and log sigma_a of one volume and
channel). The posterior covariance of the linearised model is (F / b + Sigma_0^-1)^-1; its diagonal gives each
parameter's standard deviation sd, centred on the fitted value (the mode where the prior is flat inside its
range): the interval is value +- 2 sd (in the logarithm for sigma_s and sigma_a).

**Determined or not.** A parameter is determined where the capture narrows the literature's range at least
three-fold: sd <= sd_0 / 3 (``DETERMINED_RATIO``, sd_0 from Sigma_0). The similarity relation: light that has
scattered a few times through a tissue sees its scattering sigma_s and its phase function's mean cosine g mostly
through the reduced scattering sigma_s (1 - g), and along that curved valley the fit can end far from the truth
where the linearised interval is narrow about the wrong value: a tissue with any phase-function parameter
undetermined has its scattering, its absorption and its other phase-function parameters undetermined too (on
translucent-forward a tooth's enamel g2, read at its open g1 0.57 (truth 0.78), came out -0.33 with an interval
-0.53 to -0.13 that missed the truth -0.10: the g2 the images prefer moves with g1 along the valley). An
undetermined parameter's interval is the hull of value +- 2 sd and the literature's range (clipped to the valid
range): the capture narrows it no further than the literature, and the report says so (``interval_from``).
Measured on the Mitsuba capture translucent-forward of ``bench teeth-extrapolation``: the linearised intervals of
the 30 scattering and absorption parameters of its tissues (every phase function open) missed the truth in 22, by
up to a factor 2.8; every truth lay inside the literature's range.

Open combinations: F / b's eigen-decomposition sum w_i v_i v_i^T. A combination v_i with two standard deviations
2 / sqrt(w_i) beyond ``OPEN_STEPS`` steps (or w_i <= 0: below the estimator's own noise) is one the capture
leaves open; the report names its two largest parts in words, and each tissue whose phase function is open.
"""

from __future__ import annotations

import numpy as np

from ..errors import UserError
from .capture import Capture
from .literature_init import ALBEDO_RANGE, G_VALUES, SIGMA_RANGE_MM
from .param_vector import RANGES, ParamLayout, scene_to_vector
from .scene import TeethScene
from .sensitivity import capture_sensitivity, default_directions
from .task_map import TaskMap

G_STEP = 0.05  # the phase-function parameters' step (g1, g2, beta are 0..1-ish numbers)
OPEN_STEPS = 5.0  # two standard deviations beyond 5 steps (a 50 % change of sigma_s or sigma_a): not determined
ALONE = 0.3  # an open combination whose second part is below this share of its first: one parameter alone
DETERMINED_RATIO = 1.0 / 3.0  # determined: the capture narrows the literature's standard deviation this much
LOG_STEP = 0.1  # a sigma_s or sigma_a direction's step in the logarithm (10 % up, to first order)


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
        if e.kind in ("g", "tooth_g1", "beta"):
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
                        block: int = 8, seed: int = 7, task_map: TaskMap | None = None) -> dict:
    """Each parameter's fitted value and 2-standard-deviation interval, and the combinations the capture leaves
    open (module docstring), for ``fit_report.json``. ``light_ids``: the lights the fit used (default all);
    ``task_map`` computes the renders (``sensitivity.capture_sensitivity``; default: this process)."""
    if light_ids is not None:
        ids = np.asarray(light_ids, dtype=np.int64)
        capture = Capture(capture.cameras, [capture.lights[i] for i in ids],
                          None if capture.images is None else capture.images[:, ids], capture.masks)
    layout = ParamLayout(scene)
    names, dirs, steps = _directions(scene, layout)
    noise = capture_noise_variance(capture)
    sens = capture_sensitivity(scene, capture, dirs, passes=passes, block=block, noise_variance=noise, seed=seed,
                               task_map=task_map)
    values = [_value(scene, layout, n) for n in names]
    out = intervals_from_information(sens["information"], names, steps, values, reduced_chi2=sens["reduced_chi2"])
    out.update({"noise_variance": noise, "passes": passes, "block": block,
                "method": "linearised posterior at the fit: the capture's image Jacobian (unbiased over independent "
                          "Monte Carlo passes, 8 x 8 tiles), its noise estimated from its own pixels, the fit's "
                          "reduced chi-square, and the literature's range of each parameter as the prior "
                          "(core/teeth/fit_intervals.py)"})
    return out


def _log_moments(n: int = 4001) -> tuple[np.ndarray, np.ndarray]:
    """Mean (2,) and covariance (2, 2) of (log sigma_s, log sigma_a) for log sigma_t uniform over
    ``SIGMA_RANGE_MM`` and kappa = log10(1 - albedo) uniform over ``ALBEDO_RANGE`` (independent; midpoint
    quadrature in kappa, closed form in log sigma_t)."""
    lo_s, hi_s = np.log(SIGMA_RANGE_MM[0]), np.log(SIGMA_RANGE_MM[1])
    k_lo, k_hi = np.log10(1.0 - ALBEDO_RANGE[1]), np.log10(1.0 - ALBEDO_RANGE[0])
    kappa = k_lo + (np.arange(n) + 0.5) * (k_hi - k_lo) / n
    parts = np.stack([np.log1p(-10.0 ** kappa), kappa * np.log(10.0)])  # log albedo, log(1 - albedo)
    mean_t, var_t = 0.5 * (lo_s + hi_s), (hi_s - lo_s) ** 2 / 12.0
    mean = mean_t + parts.mean(axis=1)
    cov = np.cov(parts, bias=True) + var_t  # log sigma_t is shared by both
    return mean, cov


def literature_range(name: str) -> tuple[float, float]:
    """The literature's range of a direction's parameter (module docstring), in its own unit."""
    if ".sigma_s[" in name:
        return SIGMA_RANGE_MM[0] * ALBEDO_RANGE[0], SIGMA_RANGE_MM[1] * ALBEDO_RANGE[1]
    if ".sigma_a[" in name:
        return SIGMA_RANGE_MM[0] * (1.0 - ALBEDO_RANGE[1]), SIGMA_RANGE_MM[1] * (1.0 - ALBEDO_RANGE[0])
    if name.endswith(".g1"):
        return float(min(G_VALUES)), float(max(G_VALUES))
    if name.endswith(".g2"):
        return RANGES["g"]
    if name.endswith(".beta"):
        return RANGES["beta"]
    if ".c[" in name:
        return RANGES["c"]
    raise ValueError(f"no literature range for {name!r}")


def _valid_range(name: str) -> tuple[float, float]:
    """Where an interval is clipped: the parameter's valid values."""
    if ".sigma_" in name:
        return 0.0, float("inf")
    if name.endswith(".g1") and not name.startswith("gums."):
        return RANGES["tooth_g1"]  # the fit keeps a tooth's forward lobe within the literature's range
    return RANGES["beta"] if name.endswith(".beta") else RANGES["c"] if ".c[" in name else RANGES["g"]


def prior_covariance(names: list[str], steps: list[float]) -> np.ndarray:
    """Sigma_0 of the module docstring in the directions' coordinates (steps): (K, K)."""
    k = len(names)
    cov = np.zeros((k, k))
    _, log_cov = _log_moments()
    index = {n: i for i, n in enumerate(names)}
    for i, n in enumerate(names):
        if ".sigma_s[" in n or ".sigma_a[" in n:
            me = 0 if ".sigma_s[" in n else 1
            cov[i, i] = log_cov[me, me] / LOG_STEP ** 2
            other = index.get(n.replace(".sigma_s[", ".sigma_a[") if me == 0 else n.replace(".sigma_a[", ".sigma_s["))
            if other is not None:
                cov[i, other] = log_cov[0, 1] / LOG_STEP ** 2
        else:
            lo, hi = literature_range(n)
            cov[i, i] = (hi - lo) ** 2 / 12.0 / steps[i] ** 2
    return cov


def intervals_from_information(information: np.ndarray, names: list[str], steps: list[float],
                               values: list[float], reduced_chi2: float = 1.0) -> dict:
    """The intervals and open combinations of the module docstring from the information matrix F of the
    directions (in steps) and the fit's reduced chi-square: ``{"parameters": [...], "undetermined": [...],
    "determined_count": int, "reduced_chi2": float}``."""
    info = 0.5 * (np.asarray(information, dtype=np.float64) + np.asarray(information, dtype=np.float64).T)
    birge = float(reduced_chi2) if np.isfinite(reduced_chi2) and reduced_chi2 > 1.0 else 1.0
    info = info / birge
    w, v = np.linalg.eigh(info)
    info_psd = (v * np.maximum(w, 0.0)) @ v.T  # estimator noise can make F indefinite: no information there
    prior = prior_covariance(names, steps)
    post = np.linalg.inv(info_psd + np.linalg.inv(prior))
    sd = np.sqrt(np.maximum(np.diag(post), 0.0))
    sd0 = np.sqrt(np.diag(prior))
    params = []
    for k, (n, step, val) in enumerate(zip(names, steps, values, strict=True)):
        entry = {"name": n, "words": _words(n), "value": float(val), "determined": bool(sd[k] <= DETERMINED_RATIO
                                                                                         * sd0[k]),
                 "interval_2sigma": _interval(n, float(val), 2.0 * float(sd[k]) * step), "narrowing": float(
                     sd[k] / sd0[k])}
        params.append(entry)
    determined = w > (2.0 / OPEN_STEPS) ** 2
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
    for p in params:
        p["interval_from"] = "capture" if p["determined"] else "literature range (the capture leaves it open)"
        if not p["determined"]:  # the capture narrows it no further than the literature
            lo, hi = literature_range(p["name"])
            vlo, vhi = _valid_range(p["name"])
            p["interval_2sigma"] = [max(min(p["interval_2sigma"][0], lo), vlo), min(max(p["interval_2sigma"][1], hi),
                                                                                     vhi)]
    return {"parameters": params, "undetermined": open_combinations,
            "determined_count": int(sum(p["determined"] for p in params)), "reduced_chi2": birge}


def _interval(name: str, value: float, half_steps: float) -> list[float]:
    """value +- half (``half_steps`` in the direction's unit: a logarithm for sigma_s and sigma_a), clipped to
    the valid range."""
    if ".sigma_s[" in name or ".sigma_a[" in name:
        return [value * float(np.exp(-half_steps)), value * float(np.exp(half_steps))]
    lo, hi = _valid_range(name)
    return [max(value - half_steps, lo), min(value + half_steps, hi)]


def _tissue(name: str) -> str:
    """The tissue a parameter belongs to: ``tooth0.enamel`` of ``tooth0.enamel.sigma_s[0]`` or ``.g1``."""
    for key in (".sigma_s[", ".sigma_a[", ".g1", ".g2", ".beta"):
        if key in name:
            return name.split(key)[0]
    return ""


def _similarity_open(params: list[dict]) -> list[dict]:
    """The similarity relation (module docstring): a tissue whose phase function the capture leaves open (any of
    g1, g2, beta) has its scattering, its absorption and the rest of its phase function marked undetermined too
    (in ``params``, in place); one open combination per such tissue, in words."""
    open_phase = {_tissue(p["name"]) for p in params
                  if not p["determined"] and p["name"].endswith((".g1", ".g2", ".beta"))}
    out = []
    for tissue in sorted(open_phase):
        moved = [p for p in params if _tissue(p["name"]) == tissue and p["determined"]]
        for p in moved:  # its scattering, absorption and the rest of its phase function
            p["determined"] = False
        words = tissue.replace(".", " ")
        out.append({"parameters": [f"{tissue}.sigma_s", f"{tissue}.g1"], "weights": [],
                    "text": f"{words} scattering and its phase function trade off: the capture measures at most "
                            "their combination, the reduced scattering sigma_s (1 - g), and the absorption and the "
                            "phase function's other parameters only together with it (their intervals are the "
                            "literature's range)"})
    return out


def calibration(report: dict, truth: TeethScene) -> dict:
    """How the intervals of ``report`` (``parameter_intervals``' output for a fit) hold the true values of a
    capture whose truth is known: ``inside_share`` of all parameters (one without an interval: not inside),
    ``outside_undetermined`` the parameters the truth lies outside of that the report names as undetermined, and
    ``outside_determined`` those it names as determined (each one the report should have named as undetermined);
    per parameter, its truth beside its interval."""
    layout = ParamLayout(truth)
    rows, inside, missed, open_missed = [], 0, [], []
    for p in report["parameters"]:
        value = _value(truth, layout, p["name"])
        lo_hi = p["interval_2sigma"]
        determined = bool(p.get("determined", lo_hi is not None))  # an older report: determined = has an interval
        hit = lo_hi is not None and min(lo_hi) <= value <= max(lo_hi)
        inside += hit
        if not hit:
            (missed if determined else open_missed).append(p["name"])
        rows.append({"name": p["name"], "truth": value, "fitted": p["value"], "interval_2sigma": lo_hi,
                     "determined": determined, "inside": bool(hit)})
    n = len(rows)
    return {"inside_share": inside / n if n else float("nan"), "parameters": n, "inside": int(inside),
            "undetermined": [r["name"] for r in rows if not r["determined"]],
            "outside_undetermined": open_missed, "outside_determined": missed, "per_parameter": rows}


def summary(report: dict) -> str:
    """One line for the panel: how many parameters the capture determines."""
    n = len(report["parameters"])
    k = report["determined_count"]
    text = f"The capture determines {k} of {n} parameters"
    if k < n:
        text += f"; {n - k} it leaves open span the literature's range"
    return text


def _unit(name: str) -> str:
    return " /mm" if ".sigma_" in name else ""


def parameter_lines(report: dict) -> list[str]:
    """One line per parameter for the panel, in words: 'tooth0 enamel scattering (red): 0.79 /mm, 0.7-0.9
    (measured)' or '... 0.79 /mm, open: 0.15-30 (literature)'."""
    lines = []
    for p in report["parameters"]:
        lo, hi = p["interval_2sigma"]
        where = "measured" if p["determined"] else "open: the literature's range"
        lines.append(f"{p['words']}: {p['value']:.3g}{_unit(p['name'])}, {lo:.3g} to {hi:.3g} ({where})")
    return lines
