"""stackgen-monitor as a process beside a real run: /metrics read with Prometheus' own parser
(Debian's python3-prometheus-client) equals what the generator and the writer print when they
end; /healthz, the page and its JSON answer; it serves this host only unless told."""

import json
import os
import re
import time
import urllib.error
import urllib.request

from prometheus_client.parser import text_string_to_metric_families

from conftest import BIN, free_url, quick_config


def start_monitor(processes, url, *extra):
    """A monitor on a port the system picks; its base URL once it serves."""
    monitor = processes([os.path.join(BIN, "stackgen-monitor"), "--port", "0", "--lcm-url", url,
                         *extra], "monitor")
    assert monitor.wait_for_output("serving http://", 10), monitor.stderr()
    return monitor, re.search(r"serving (http://[0-9.]+:\d+/)", monitor.stdout()).group(1)


def get(base, path):
    with urllib.request.urlopen(base + path, timeout=10) as response:
        return response.status, response.headers.get("Content-Type"), response.read().decode()


def samples(text):
    """Every sample of a Prometheus text: (name, labels as a sorted tuple) -> value."""
    found = {}
    for family in text_string_to_metric_families(text):
        for sample in family.samples:
            found[(sample.name, tuple(sorted(sample.labels.items())))] = sample.value
    return found


# a generator and a writer run 6 scenes while the monitor listens: its counters of each, parsed
# as Prometheus parses them, are what each prints as it ends (scenes published, stored,
# received); the page and its JSON show both; the monitor binds to 127.0.0.1 by default
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
        by_process = {dict(labels)["process"]: value for labels, value in scenes.items()}
        if by_process == {"stackgen": published, "stackgen-coco": stored}:
            break
        assert time.monotonic() < deadline, by_process
        time.sleep(0.1)
    writer = [labels for labels in scenes if dict(labels)["process"] == "stackgen-coco"][0]
    assert found[("stackgen_received_total", writer)] == received
    assert found[("stackgen_lost", writer)] == 0
    generator_labels = [labels for labels in scenes if dict(labels)["process"] == "stackgen"][0]
    assert dict(generator_labels)["generator_id"] == "0"
    assert found[("stackgen_run_state", generator_labels)] == 1  # ended: all stored
    assert found[("stackgen_stage_seconds", generator_labels + (("stage", "render"),))] > 0
    assert found[("stackgen_monitor_status_messages_total", ())] >= 2

    assert get(base, "healthz")[2] == "ok\n"
    status, content_type, page = get(base, "")
    assert content_type.startswith("text/html") and "stackgen monitor" in page
    table = json.loads(get(base, "status.json")[2])
    assert sorted(p["process"] for p in table["processes"]) == ["stackgen", "stackgen-coco"]
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
