"""The report of a reconstruction: ``result.json``, one HTML page and its figures.

Protocol
--------
``write(out_dir, reconstruction) -> Path`` (the HTML page) writes into ``out_dir``:

* ``result.json``  :func:`jaxocean.reconstruct.result_dict`: ``spectrum.hs_m``,
  ``spectrum.tp_s``, ``spectrum.direction_deg``, ``spectrum.peak_observed``, the fitted
  ``waves``, and per stage ``stages.NAME.success``, ``seconds`` and ``message``.
* ``frames.png``   input frames, reconstructed normals and roughness, re-rendered frames,
  display residuals and the outlier mask, at the first, middle and last frame.
* ``sea.png``      the fitted waves' amplitude spectrum against frequency with the fitted
  JONSWAP density, and a polar plot of the wave directions.
* ``dispersion.png`` the images' space-time spectrum with the dispersion shell.
* ``forecast.png`` forecast frames (titled by their time after the last frame) and the
  re-edited views of the last frame (titled so).
* ``report.html``  all of the above with every stage's flag and time; a banner says when a
  stage failed, i.e. when the numbers are not backed by a model that explains the footage.

Every file is written atomically (:func:`jaxocean.files.atomic_write`).
"""

from __future__ import annotations

import html
import math
from pathlib import Path

import numpy as np

from jaxocean import plots, render
from jaxocean import spectrum as spec
from jaxocean.files import atomic_write, write_json
from jaxocean.waves import GRAVITY

__all__ = ["write", "rerender"]


def rerender(result, indices):
    """Linear frames ``(len(indices), H, W, 3)`` of the final waves and lighting at the
    sequence's ``indices`` (times), times the fitted exposure when stage 5 ran (the
    geometric mean of per-frame exposures)."""
    import jax

    from jaxocean.fit.photometric import mean_exposure

    seq = result.sequence
    waves = result.sea["waves"]
    photo = result.photometric
    ok = photo is not None and result.stages["photometric"].success
    lighting = photo.lighting if ok else result.lighting.lighting
    exposure = mean_exposure(photo) if ok else 1.0
    plan = render.full_plan(int(np.asarray(waves.omega).shape[0]))
    frames = jax.vmap(lambda t: render.render(waves, seq.camera, lighting, t, plan=plan))(
        np.asarray(seq.times[indices], np.asarray(waves.omega).dtype))
    return exposure * np.asarray(frames)


def _display(linear, seq):
    """Linear frames as the footage's display values (its response), in [0, 1]."""
    from jaxocean import radiometry

    return np.clip(np.asarray(radiometry.to_display(np.asarray(linear), seq.response)), 0.0, 1.0)


def _frames_figure(path, result):
    seq, geo = result.sequence, result.geometry
    T = len(seq.times)
    idx = sorted({0, T // 2, T - 1})
    model = rerender(result, np.asarray(idx))
    model_display = _display(model, seq)
    observed = seq.display[idx]
    residual = np.abs(model_display - observed).mean(-1)
    rows = []
    photo = result.photometric
    outliers = None
    if photo is not None and result.stages["photometric"].success is not None:
        # stage 5 saw a subset of the frames: its outlier mask at the nearest fitted time
        fitted_times = np.asarray(result.stages["photometric"].details.get("times", []), np.float64)
        if fitted_times.size == len(photo.outliers):
            outliers = [np.asarray(photo.outliers[int(np.argmin(np.abs(fitted_times - seq.times[i])))], np.float32)
                        for i in idx]
    for r, i in enumerate(idx):
        mask = np.asarray(geo.mask[i])
        row = [observed[r], plots.normal_to_rgb(geo.normal[i], mask), plots.roughness_to_rgb(geo.roughness[i], mask),
               model_display[r], plots.log_to_rgb(residual[r] + 1e-6, vmin=1e-3, vmax=0.3)]
        if outliers is not None:
            row.append(np.repeat(outliers[r][..., None], 3, -1))
        rows.append(row)
    titles = ["input (rectified)", "normal (net)", "roughness (net)", "re-rendered", "|display residual| 1e-3..0.3"]
    return plots.contact_sheet(path, rows, col_titles=titles + (["outliers (stage 5)"] if outliers else []),
                               row_titles=[f"t = {_time_label(seq.times[i], seq.times)} s" for i in idx])


def _time_label(t, times) -> str:
    """A frame time [s] with the decimals the frame step needs (one decimal for 0.25 s
    steps showed 0.25 s as 0.2 s, and 30 fps frames 0.03 s apart as one time)."""
    steps = np.diff(np.asarray(times, np.float64))
    step = float(np.min(steps)) if steps.size and np.min(steps) > 0 else 1.0
    decimals = int(np.clip(np.ceil(-np.log10(step)) + 1, 1, 6))
    return f"{float(t):.{decimals}f}"


def _sea_figure(path, result):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    waves = result.sea["waves"]
    sfit = result.sea["spectrum_fit"]
    h, w, th = (np.asarray(x, np.float64) for x in (waves.amplitude, waves.omega, waves.theta))
    # a flat sea handed on (no wave found) is drawn as no wave, not as its zero-amplitude stand-in
    real = h > 0
    h, w, th = h[real], w[real], th[real]
    fig = plt.figure(figsize=(10, 4))
    ax = fig.add_subplot(1, 2, 1)
    if real.any():
        ax.stem(w, h, basefmt=" ")
    ax.set_xlabel("frequency omega [rad/s]")
    ax.set_ylabel("amplitude h [m]", color="C0")
    geo = result.sea.get("geometry_spectrum") or {}
    if not real.any():
        ax.text(0.5, 0.5, "no wave found", ha="center", va="center", transform=ax.transAxes)
        if geo.get("k_rad_m"):
            # the geometry's own spectrum over the band, by frequency (omega = sqrt(g k))
            om = np.sqrt(GRAVITY * np.asarray(geo["k_rad_m"]))
            ax.twinx().step(om, geo["elevation_m2"], "C2", where="mid")
            ax.set_xlim(0.0, 1.1 * om.max())
            ax.set_title("no wave found; green: geometry's spectrum [m^2/bin]")
    if sfit is not None:
        om = np.linspace(max(0.2, 0.5 * w.min()), 1.5 * w.max(), 200)
        ax2 = ax.twinx()
        ax2.plot(om, np.asarray(spec.spectrum_density(sfit.spectrum, om)), "C1")
        ax2.set_ylabel("fitted JONSWAP S(omega) [m^2 s]", color="C1")
        lo, hi = sfit.omega_band
        ax.axvspan(lo, hi, color="0.9", zorder=-1)
    if real.any() or not geo.get("k_rad_m"):
        ax.set_title(f"fitted waves ({len(h)}); grey: observed band")
    pa = fig.add_subplot(1, 2, 2, projection="polar")
    compass = result.sequence.compass
    angles = (np.pi / 2 - th) if compass else th
    if compass:
        pa.set_theta_zero_location("N")
        pa.set_theta_direction(-1)
    pa.scatter(angles, 2 * np.pi / w, s=20 + 400 * h / max(h.max(initial=0.0), 1e-9), alpha=0.6)
    plots.polar_room(pa, 2 * np.pi / w)
    if not real.any() and geo.get("direction_deg") is not None:
        # the geometry spectrum's mean direction (report convention) and its 1-sigma wedge
        mean = np.radians(geo["direction_deg"])
        sigma = np.radians(geo["direction_std_deg"])
        period = geo["peak_period_s"]
        pa.plot([mean, mean], [0.0, period], "C2", lw=2)
        pa.fill_between(np.linspace(mean - sigma, mean + sigma, 30), 0.0, period, color="C2", alpha=0.2)
        plots.polar_room(pa, [period])
    pa.set_title("direction of travel (radius: period [s])" + (", from north" if compass else ", from +x"))
    fig.tight_layout()
    return plots.save_figure(fig, path)


def _forecast_figure(path, result):
    out = result.outlook
    seq = result.sequence
    row1 = list(_display(out["forecast"], seq))
    row2 = [_display(out["lower"], seq), _display(out["new_sun"], seq)]
    titles = [f"+{t - seq.times[-1]:.0f} s" for t in out["times"]]
    # the re-edited views show the last observed frame, not the forecast times above them
    last = f"t = {_time_label(seq.times[-1], seq.times)} s (last frame)"
    return plots.contact_sheet(path, [row1, row2], col_titles=titles,
                               row_titles=["forecast", "re-edited: lower camera / new sun"],
                               cell_titles=[None, [f"lower camera, {last}", f"new sun, {last}"]])


def _banner(data) -> str:
    failed = [n for n, s in data["stages"].items() if not s["success"]]
    if not failed:
        return ('<p class="ok">Every stage succeeded: the fitted waves and lighting explain the footage within its '
                'noise.</p>')
    return ('<p class="bad"><b>Stages failed: ' + ", ".join(failed) + '.</b> The model does not explain this footage '
            'everywhere; the numbers below rest on the failed stages and are not measurements. Read each stage\'s '
            'message.</p>')


_SURFACES = {"rows": "the plane-hit (rows) model", "hits": "the displaced-surface (hits) model"}


def _stage_note(stage) -> str:
    """A stage's message, with what a wave fit measured and on which surface model."""
    d = stage.get("details") or {}
    note = stage.get("message") or ""
    if d.get("surface") in _SURFACES:
        fitted = (f"{d.get('n_waves')} waves ({d.get('determined')} determined) fitted on "
                  f"{_SURFACES[d['surface']]}")
        note = fitted + (": " + note if note else "")
    return note


def _html(data, figures) -> str:
    s = data["spectrum"]

    def num(v, fmt="{:.3g}"):  # a NaN (an unconfirmed estimate) reads as missing, not "nan"
        return "n/a" if v is None or math.isnan(v) else fmt.format(v)

    rows = "".join(
        f"<tr><td>{html.escape(n)}</td><td class={'ok' if st['success'] else 'bad'}>"
        f"{'ok' if st['success'] else 'FAILED'}</td><td>{st['seconds']:.1f} s</td>"
        f"<td>{html.escape(_stage_note(st))}</td></tr>" for n, st in data["stages"].items())
    # the spectrum stage states a bound whenever the peak is not observed
    bound = f" ({html.escape(s['bound'])})" if s.get("bound") else ""
    if not s.get("success"):
        bound += " <b class=bad>(not a measurement: the spectrum stage failed)</b>"
    disp = s.get("dispersion") or {}
    geo = s.get("geometry_spectrum") or {}
    headline = (f"<ul><li>Hs = {num(s.get('hs_m'))} m &plusmn; {num(s.get('hs_std_m'))}{bound}</li>"
                f"<li>Tp = {num(s.get('tp_s'))} s &plusmn; {num(s.get('tp_std_s'))}{bound}</li>"
                f"<li>mean direction of travel: {num(s.get('direction_deg'), '{:.0f}')} &plusmn; "
                f"{num(s.get('direction_std_deg'), '{:.0f}')} deg "
                f"({html.escape(s.get('direction_convention', ''))}); spreading s_max = "
                f"{num(s.get('spreading_s_max'))} &plusmn; {num(s.get('spreading_std'))}</li>"
                f"<li>source: {html.escape(s.get('source') or 'none')}</li>"
                f"<li>mean square slope (geometry): {num(s.get('mean_square_slope'))}</li>"
                + (f"<li>the geometry's space-time spectrum: {html.escape(geo['message'])}; mean direction "
                   f"{num(geo.get('direction_deg'), '{:.0f}')} &plusmn; {num(geo.get('direction_std_deg'), '{:.0f}')} "
                   f"deg</li>" if geo else "") +
                (f"<li>space-time spectrum: {num(disp.get('ratio'))} times more energy on the dispersion shell "
                 f"than without dispersion; its peak period {num(s.get('dispersion_peak_period_s'))} s, direction "
                 f"{num(s.get('dispersion_direction_deg'), '{:.0f}')} deg</li>" if disp else
                 # no check (too few frames): say so, not "n/a times more energy"
                 f"<li>space-time spectrum: {html.escape(s.get('dispersion_note') or 'not computed')}</li>")
                + "</ul>")
    imgs = "".join(f'<h2>{html.escape(t)}</h2><img src="{html.escape(p.name)}">' for t, p in figures)
    return f"""<!doctype html><html><head><meta charset="utf-8"><title>jaxocean reconstruction</title>
<style>body{{font-family:sans-serif;max-width:1400px;margin:2em}} .ok{{color:#060}} .bad{{color:#a00}}
td{{padding:2px 10px}} img{{max-width:100%}}</style></head><body>
<h1>Reconstruction</h1>{_banner(data)}{headline}
<h2>Stages</h2><table><tr><th>stage</th><th>flag</th><th>time</th><th>message</th></tr>{rows}</table>
{imgs}<p>Numbers: <a href="result.json">result.json</a>.</p></body></html>"""


def write(out_dir, result) -> Path:
    """Write ``result.json``, the figures and ``report.html`` (module docstring) into
    ``out_dir``; returns the HTML page's path."""
    from jaxocean import reconstruct, spacetime

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    data = reconstruct.result_dict(result)
    write_json(out / "result.json", data)
    figures = [("Frames, geometry, re-rendering and residuals", _frames_figure(out / "frames.png", result)),
               ("Waves and spectrum", _sea_figure(out / "sea.png", result))]
    check = result.sea.get("check")
    if check is not None:
        figures.append(("Space-time spectrum of the images (evidence of linear waves)",
                        spacetime.plot_dispersion(check, out / "dispersion.png")))
    figures.append(("Forecast and re-edited views", _forecast_figure(out / "forecast.png", result)))
    page = out / "report.html"
    atomic_write(page, lambda tmp: Path(tmp).write_text(_html(data, figures)))
    return page
