"""stackgen-monitor as a process beside a real run: /metrics read with Prometheus' own parser
(Debian's python3-prometheus-client) equals what the generator and the writer print when they
end; /healthz, the page and its JSON answer; it serves this host only unless told; the page in
headless Chromium shows the latest scenes and marks a stalled generator."""

import json
import os
import re
import signal
import subprocess
import time
import urllib.error
import urllib.request

import cv2
import numpy as np
from prometheus_client.parser import text_string_to_metric_families

from conftest import BIN, free_url, quick_config


def start_monitor(processes, url, *extra):
    """A monitor on a port the system picks; its base URL once it serves."""
    monitor = processes([os.path.join(BIN, "stackgen-monitor"), "--port", "0", "--lcm-url", url,
                         *extra], "monitor")
    assert monitor.wait_for_output("serving http://", 10), monitor.stderr()
    return monitor, re.search(r"serving (http://[0-9.]+:\d+/)", monitor.stdout()).group(1)


def get(base, path):
    """(status, content type, body: text, or bytes for an image)."""
    with urllib.request.urlopen(base + path, timeout=10) as response:
        body = response.read()
        kind = response.headers.get("Content-Type")
        return response.status, kind, body if kind.startswith("image/") else body.decode()


def samples(text):
    """Every sample of a Prometheus text: (name, labels as a sorted tuple) -> value."""
    found = {}
    for family in text_string_to_metric_families(text):
        for sample in family.samples:
            found[(sample.name, tuple(sorted(sample.labels.items())))] = sample.value
    return found


# a generator and a writer run 6 scenes while the monitor listens: its counters of each, parsed
# as Prometheus parses them, are what each prints as it ends (scenes published, stored,
# received); the page and its JSON show both (and the monitor itself, a consumer like any); the
# monitor binds to 127.0.0.1 by default
def test_metrics_equal_what_the_processes_print(tmp_path, processes):
    url, count = free_url(), 6
    monitor, base = start_monitor(processes, url)
    assert base.startswith("http://127.0.0.1:")
    coco = processes([os.path.join(BIN, "stackgen-coco"), "--out", tmp_path / "coco", "--count",
                      count, "--lcm-url", url], "coco")
    assert coco.wait_for_output("listening", 10), coco.stderr()
    generator = processes([os.path.join(BIN, "stackgen"), "--config", quick_config(tmp_path),
                           "--count", count, "--seed", 4, "--lcm-url", url,
                           "--cache-dir", tmp_path / "cache"], "stackgen")
    assert generator.wait(120) == 0, generator.stderr()
    assert coco.wait(60) == 0, coco.stderr()

    # what they printed
    published = int(re.search(r"stackgen: (\d+) scenes in", generator.stderr()
                              + generator.stdout()).group(1))
    delivery = re.search(r"delivery: (\d+) scenes received, (\d+) stored",
                         coco.stdout() + coco.stderr())
    received, stored = int(delivery.group(1)), int(delivery.group(2))
    assert published == stored == count

    # what the monitor says, once it heard their last statuses (sent as each ends; up to 5 s)
    deadline = time.monotonic() + 5
    while True:
        status, content_type, text = get(base, "metrics")
        assert status == 200 and content_type.startswith("text/plain; version=0.0.4")
        found = samples(text)
        scenes = {labels: value for (name, labels), value in found.items()
                  if name == "stackgen_scenes_total"}
        by_process = {dict(labels)["process"]: value for labels, value in scenes.items()
                      if dict(labels)["process"] != "stackgen-monitor"}
        if by_process == {"stackgen": published, "stackgen-coco": stored}:
            break
        assert time.monotonic() < deadline, by_process
        time.sleep(0.1)
    writer = [labels for labels in scenes if dict(labels)["process"] == "stackgen-coco"][0]
    assert found[("stackgen_received_total", writer)] == received
    assert found[("stackgen_lost", writer)] == 0
    generator_labels = [labels for labels in scenes if dict(labels)["process"] == "stackgen"][0]
    assert dict(generator_labels)["generator_id"] == "0"
    # its run, from its config, as the writers name it
    assert dict(generator_labels)["run"].startswith("seed 4, config ")
    # its redraws by cause and bytes, as its summary says them
    redraws = re.search(r"(\d+) drops redrawn \((\d+) unsettled, (\d+) outside the bin, "
                        r"(\d+) interpenetrating\)", generator.stderr() + generator.stdout())
    for cause, count in zip(("unsettled", "outside", "interpenetrating"), redraws.groups()[1:]):
        labels = tuple(sorted(dict(generator_labels, cause=cause).items()))
        assert found[("stackgen_redraws_total", labels)] == int(count)
    assert found[("stackgen_scene_bytes_total", generator_labels)] > published * 10000
    assert found[("stackgen_run_state", generator_labels)] == 1  # ended: all stored
    assert found[("stackgen_run_state", writer)] == 1  # ended: its --count stored, not quiet
    render = tuple(sorted(dict(generator_labels, stage="render").items()))
    assert found[("stackgen_stage_seconds", render)] > 0
    assert found[("stackgen_monitor_status_messages_total", ())] >= 2

    assert get(base, "healthz")[2] == "ok\n"
    status, content_type, page = get(base, "")
    assert content_type.startswith("text/html") and "stackgen monitor" in page
    table = json.loads(get(base, "status.json")[2])
    assert sorted(p["process"] for p in table["processes"]) == [
        "stackgen", "stackgen-coco", "stackgen-monitor"]
    try:
        get(base, "nothing")
        raise AssertionError("an unknown path answered")
    except urllib.error.HTTPError as error:
        assert error.code == 404
    assert monitor.popen.poll() is None


# a port that is not free is refused in one line naming it; a bad address too
def test_bad_address_and_port_in_use(tmp_path, processes):
    url = free_url()
    first, base = start_monitor(processes, url)
    port = base.rsplit(":", 1)[1].rstrip("/")
    second = processes([os.path.join(BIN, "stackgen-monitor"), "--port", port, "--lcm-url", url],
                       "second")
    assert second.wait(10) == 1
    assert ("127.0.0.1:%s" % port) in second.stderr() and len(second.stderr().splitlines()) == 1
    bad = processes([os.path.join(BIN, "stackgen-monitor"), "--bind", "localhost", "--lcm-url",
                     url], "bad")
    assert bad.wait(10) == 1
    assert "localhost" in bad.stderr()


def screenshot(base, path):
    """The page as headless Chromium draws it after 3 s of its own time, as an image."""
    shot = subprocess.run(["chromium", "--headless", "--no-sandbox", "--disable-gpu",
                           "--hide-scrollbars", "--window-size=1280,1000",
                           "--virtual-time-budget=3000", "--screenshot=%s" % path, base],
                          capture_output=True, text=True, timeout=60)
    assert shot.returncode == 0, shot.stderr
    picture = cv2.imread(str(path))
    assert picture is not None, "no screenshot"
    return picture


def wait_for(condition, seconds, what):
    deadline = time.monotonic() + seconds
    while not condition():
        assert time.monotonic() < deadline, what
        time.sleep(0.2)


# the page during a run: not blank, the latest scenes drawn under the table (the sheet's dark
# background and its coloured tiles); a generator stopped with SIGSTOP is marked quiet within
# 5 to 8 s, in the JSON and on the page (its row in red)
def test_page_shows_scenes_and_a_stalled_generator(tmp_path, processes):
    url, count = free_url(), 200
    monitor, base = start_monitor(processes, url)
    processes([os.path.join(BIN, "stackgen-coco"), "--out", tmp_path / "coco", "--count", count,
               "--lcm-url", url], "coco")
    generator = processes([os.path.join(BIN, "stackgen"), "--config", quick_config(tmp_path),
                           "--count", count, "--lcm-url", url, "--cache-dir",
                           tmp_path / "cache"], "stackgen")

    def status():
        return json.loads(get(base, "status.json")[2])["processes"]

    def generator_row():
        rows = [p for p in status() if p["process"] == "stackgen"]
        return rows[0] if rows else None

    wait_for(lambda: (generator_row() or {}).get("scenes", 0) >= 3, 60, "no scenes")
    assert get(base, "latest.jpg")[1] == "image/jpeg"
    running = screenshot(base, tmp_path / "running.png")
    assert running.std() > 20, "a blank page"
    # the sheet: a dark band (its legend and gaps) and many colours below the table
    below = running[300:, :, :]
    dark = np.all(below < 60, axis=2).mean()
    colours = len(np.unique((below // 32).reshape(-1, 3), axis=0))
    assert dark > 0.02 and colours > 40, (dark, colours)
    red = np.all(running == [221, 221, 255], axis=2).sum()  # BGR of the quiet rows' #fdd
    assert red == 0

    os.kill(generator.popen.pid, signal.SIGSTOP)
    try:
        stopped = time.monotonic()
        wait_for(lambda: generator_row()["quiet"], 12, "the stalled generator is not marked")
        assert time.monotonic() - stopped < 10
        stalled = screenshot(base, tmp_path / "stalled.png")
        red = np.all(stalled == [221, 221, 255], axis=2).sum()
        assert red > 2000, red
    finally:
        os.kill(generator.popen.pid, signal.SIGCONT)
    assert monitor.popen.poll() is None


# the page away from its monitor (saved and opened as a file, so its status.json cannot be
# fetched) says the monitor does not answer
def test_page_says_when_the_monitor_does_not_answer(tmp_path, processes):
    monitor, base = start_monitor(processes, free_url())
    page = tmp_path / "page.html"
    page.write_text(get(base, "")[2])
    dom = subprocess.run(["chromium", "--headless", "--no-sandbox", "--disable-gpu",
                          "--virtual-time-budget=2000", "--dump-dom", page.as_uri()],
                         capture_output=True, text=True, timeout=60)
    assert dom.returncode == 0, dom.stderr
    warnings = re.search(r'<div id="warnings">(.*?)</div>', dom.stdout, re.S)
    assert warnings, dom.stdout[-2000:]
    assert warnings.group(1) == "<p>the monitor does not answer</p>", warnings.group(1)


# a stranger floods the bus for 3 s (random bytes and real messages cut, grown and flipped on
# every channel, datagrams no LCM library sends): the monitor stays up, answers, counts what its
# key refused, and no forged process enters its table
def test_flood_of_forged_and_malformed_messages(tmp_path, processes):
    url = free_url()
    monitor, base = start_monitor(processes, url)
    # (tests/e2e/forger.cc, built beside the tests)
    forger = os.path.join(os.path.dirname(BIN), "tests", "bin", "stackgen-forger")
    flood = processes([forger, "--lcm-url", url, "--seconds", 3, "--fuzz", 3000, "--datagrams",
                       3000, "--no-attacks"], "forger")
    assert flood.wait(60) == 0, flood.stderr()
    assert get(base, "healthz")[2] == "ok\n"
    found = samples(get(base, "metrics")[2])
    refused = sum(value for (name, labels), value in found.items()
                  if name == "stackgen_monitor_refused_total")
    assert refused > 100, found
    table = json.loads(get(base, "status.json")[2])
    assert [p["process"] for p in table["processes"]] == ["stackgen-monitor"], table
    assert monitor.popen.poll() is None


# a learner reports through stackgen.LearnerStatus: the monitor shows its steps, loss, scenes
# and reuse in /metrics and on the page's JSON, and its end once it closes; a process with
# another key (or none) is not heard
def test_learner_progress(tmp_path, processes):
    import stackgen

    url = free_url()
    monitor, base = start_monitor(processes, url)
    with stackgen.LearnerStatus(url, name="learner-under-test", process="train-live") as status:
        for step in range(1, 31):
            status.report(step, 1.0 / step, scenes_taken=step * 2, target_steps=30,
                          samples=step * 8)

        def learner():
            rows = [l for l in json.loads(get(base, "status.json")[2])["learners"]
                    if l["name"] == "learner-under-test"]
            return rows[0] if rows else None

        wait_for(lambda: learner() is not None and learner()["steps"] == 30, 10,
                 "the learner's report never arrived")
        row = learner()
        assert abs(row["loss"] - 1.0 / 30) < 1e-12 and row["scenes_taken"] == 60
        assert row["reuse"] == 4.0 and row["run_state"] == 0 and row["target_steps"] == 30
        found = samples(get(base, "metrics")[2])
        labels = (("name", "learner-under-test"), ("process", "train-live"))
        assert found[("stackgen_learner_steps_total", labels)] == 30
        assert found[("stackgen_learner_scenes_taken_total", labels)] == 60
    wait_for(lambda: learner()["run_state"] == 1, 10, "the learner's end never arrived")
    stranger = stackgen.LearnerStatus(url, name="open-learner", open_bus=True)
    stranger.report(5, 0.5)
    time.sleep(2.5)
    stranger.close()
    names = [l["name"] for l in json.loads(get(base, "status.json")[2])["learners"]]
    assert names == ["learner-under-test"], names
