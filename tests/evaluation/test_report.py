"""The HTML/Markdown report: every image is there, decodes, and loads in headless Chromium."""

import base64
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from excavator_payload.evaluation.metrics import evaluate_estimates
from excavator_payload.evaluation.report import build_report, choose_experiments

CHROMIUM = shutil.which("chromium") or ("/usr/bin/chromium" if Path("/usr/bin/chromium").exists() else None)
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"

# Marks every <img> that did not load; --dump-dom prints the DOM after the load event.
CHECK_SCRIPT = """<script>window.addEventListener('load', function () {
  var imgs = document.images, bad = 0;
  for (var i = 0; i < imgs.length; i++) { if (!(imgs[i].complete && imgs[i].naturalWidth > 0)) bad++; }
  var d = document.createElement('div'); d.id = 'img-check';
  d.textContent = 'images=' + imgs.length + ' failed=' + bad; document.body.appendChild(d);
});</script>"""


def chromium_image_check(html_path: Path, tmp_path: Path) -> tuple[int, int]:
    """(number of images, number that failed to load) as headless Chromium sees the page."""
    probe = html_path.with_name("_probe_" + html_path.name)  # same folder: relative paths resolve
    probe.write_text(html_path.read_text().replace("</body>", CHECK_SCRIPT + "</body>"))
    profile = tmp_path / "chromium-profile"
    cmd = [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
           "--disable-background-networking", "--disable-component-update", "--disable-sync",
           f"--user-data-dir={profile}", "--virtual-time-budget=5000", "--dump-dom", probe.as_uri()]
    try:
        out = subprocess.run(cmd, capture_output=True, text=True, timeout=90).stdout
    finally:
        probe.unlink()
    m = re.search(r"images=(\d+) failed=(\d+)", out)
    assert m, f"Chromium did not run the check script; output starts {out[:300]!r}"
    return int(m.group(1)), int(m.group(2))


@pytest.fixture(scope="module")
def report(mj_dataset, tmp_path_factory):
    ds = mj_dataset
    payload = ds.frame["payload"].to_numpy()
    rng = np.random.default_rng(3)
    evs = [evaluate_estimates(ds, payload + 10.0, label="Net1"),
           evaluate_estimates(ds, payload + 30 * rng.standard_normal(len(payload)), label="EKF_ideal")]
    nan_est = payload + 5.0
    nan_est[::7] = np.nan
    evs.append(evaluate_estimates(ds, nan_est, label="with gaps"))
    out = tmp_path_factory.mktemp("report")
    net_dir = out / "net1-model"
    net_dir.mkdir()
    pd.DataFrame({"epoch": np.arange(20), "sse": np.geomspace(100, 1, 20),
                  "validation_sse": np.geomspace(120, 2, 20)}).to_csv(net_dir / "training_log.csv", index=False)
    curve = pd.DataFrame({"calibration_experiments": [0, 1, 2, 5, 10], "mean_rms_kg": [90, 20, 8, 3, 2.0],
                          "bias_kg": [-80, 5, 1, 0.2, -0.1], "n_test": [20] * 5})
    paths = build_report(out / "rep", ds, evs, title="test report", settings={"seed": 11},
                         experiments=[0, 5], failures={"UKF": "fit: it broke"}, calibration=curve,
                         training_dirs={"Net1": net_dir}, notes=["a note"])
    return paths, evs


def test_report_files_and_tables(report):
    paths, evs = report
    html = paths.html.read_text()
    md = paths.markdown.read_text()
    for text in ("Thesis Table 7.1", "Thesis Table 7.2", "Thesis Figure 7.0", "Cramér–Rao", "0.4998",
                 "100.485", "54.728", "UKF", "fit: it broke", "Settings", "numpy", '"seed": 11', "a note"):
        assert text in html, text
        assert text in md, text
    assert paths.json.is_file()


def test_every_image_is_embedded_and_on_disk(report):
    paths, _ = report
    html = paths.html.read_text()
    imgs = re.findall(r"<img src='data:image/png;base64,([A-Za-z0-9+/=]+)'[^>]*data-file='([^']+)'", html)
    # Fig 7.0, CRB, 2 experiments × 3, calibration curve, training graph
    assert len(imgs) == len(re.findall(r"<img ", html)) == 10
    for data, rel in imgs:
        raw = base64.b64decode(data)
        assert raw.startswith(PNG_MAGIC)
        assert (paths.html.parent / rel).read_bytes() == raw
    md_links = re.findall(r"!\[[^\]]*\]\(([^)]+)\)", paths.markdown.read_text())
    assert len(md_links) == 10
    assert all((paths.markdown.parent / link).is_file() for link in md_links)


def test_choose_experiments_spans_payloads(mj_dataset):
    ids = choose_experiments(mj_dataset, 6)
    assert len(ids) == 6 == len(set(ids))
    p = dict(zip(mj_dataset.experiment_ids, mj_dataset.payloads))
    assert p[ids[0]] == min(p.values()) and p[ids[-1]] == max(p.values())


@pytest.mark.skipif(CHROMIUM is None, reason="headless Chromium not installed (Debian: apt-get install chromium)")
def test_report_opens_in_chromium_with_all_images(report, tmp_path):
    paths, _ = report
    n, failed = chromium_image_check(paths.html, tmp_path)
    assert n == 10 and failed == 0
    # the check can fail: a page with a broken image is caught
    broken = paths.html.with_name("broken.html")
    broken.write_text(paths.html.read_text().replace("</body>", "<img src='figures/missing.png'></body>"))
    n, failed = chromium_image_check(broken, tmp_path)
    broken.unlink()
    assert n == 11 and failed == 1


def test_report_on_machine_work_cycles(tmp_path):
    """`report` on the machine sensor set (pressures and IMUs, no joint torques): its own signal
    figure per chosen experiment (it crashed on the thesis set's joint figure before), and the
    payload figure draws the load leaving the bucket at the dump, up to which it is judged."""
    from excavator_payload.cli import main
    from excavator_payload.data.io import write_dataset
    from excavator_payload.estimators import create_estimator
    from excavator_payload.simulation.machine_sim import simulate_machine_dataset

    cycles = simulate_machine_dataset(2, seed=5, session=2, motion="work-cycle")
    est = create_estimator("inverse-dynamics", machine="cat345c-hydraulic").fit(cycles)
    est.save(tmp_path / "m")
    write_dataset(cycles, tmp_path / "c.parquet")
    assert main(["report", "--data", str(tmp_path / "c.parquet"), "--model", str(tmp_path / "m"),
                 "--out", str(tmp_path / "r")]) == 0
    figures_dir = tmp_path / "r" / "figures"
    signals = sorted(figures_dir.glob("fig_exp*_signals.png"))
    assert signals and not list(figures_dir.glob("fig_exp*_joints.png"))
    assert all(p.read_bytes()[:8] == PNG_MAGIC for p in signals)
    assert (tmp_path / "r" / "report.html").is_file()
    # the thesis' Tables 7.1 / 7.2 (its 2-link arm's estimators) are no section of a machine report
    assert "Thesis Table 7.1" not in (tmp_path / "r" / "report.html").read_text()
    from excavator_payload.evaluation import figures

    ev = evaluate_estimates(cycles, est.estimate(cycles), label="id", with_bound=False)
    fig = figures.payload_estimates(cycles, [ev], int(cycles.experiment_ids[0]))
    labels = [line.get_label() for line in fig.axes[0].get_lines()]
    assert "payload in the bucket" in labels and "dump: judged up to here" in labels
    truth = fig.axes[0].get_lines()[0].get_ydata()
    assert truth[0] == cycles.frame["payload"].iloc[0] and truth[-1] == 0.0
