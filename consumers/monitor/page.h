#pragma once

// stackgen-monitor's page (/): plain HTML and a little script that reads /status.json every
// 2 s and draws each process's state, its rate over the last minutes, and a warning for a
// process gone quiet (not heard for 5 s without saying its run ended); the learners' steps and
// loss; and under them the latest scenes (/latest.jpg), fetched again every 4 s.

namespace stackgen {

inline constexpr const char kMonitorPage[] = R"html(<!DOCTYPE html>
<html lang="en">
<head>
<meta charset="utf-8">
<title>stackgen monitor</title>
<style>
  body { font-family: sans-serif; font-size: 14px; margin: 1.2em; color: #222; }
  h1 { font-size: 1.3em; }
  table { border-collapse: collapse; }
  th, td { padding: 0.25em 0.5em; border-bottom: 1px solid #ddd; text-align: right; }
  th:nth-child(-n+3), td:nth-child(-n+3) { text-align: left; }
  td.name { max-width: 18em; overflow-wrap: anywhere; }
  tr.quiet td { background: #fdd; }
  #warnings p { background: #fdd; padding: 0.4em; margin: 0.2em 0; }
  canvas { vertical-align: middle; }
  .small { color: #777; font-size: 0.85em; }
</style>
</head>
<body>
<h1>stackgen monitor</h1>
<div id="warnings"></div>
<table>
<thead><tr><th>process</th><th>name</th><th>state</th><th>scenes</th><th>scenes/s</th>
<th>rate, last 2 min</th><th>physics ms</th><th>render ms</th><th>lost</th><th>resent</th>
<th>held back s</th><th>refused</th><th>heard</th></tr></thead>
<tbody id="rows"></tbody>
</table>
<div id="learners-box" style="display: none">
<h2 style="font-size: 1.1em">learners</h2>
<table>
<thead><tr><th>process</th><th>name</th><th>state</th><th>steps</th><th>loss</th>
<th>loss, last 2 min</th><th>scenes taken</th><th>scenes/s</th><th>reuse</th><th>heard</th></tr>
</thead>
<tbody id="learners"></tbody>
</table>
</div>
<p class="small" id="monitor"></p>
<h2 style="font-size: 1.1em">latest scenes</h2>
<img id="sheet" alt="no scene yet" src="latest.jpg">
<script>
const states = ["running", "ended", "stopped"];
function cell(text, cls) {
  const td = document.createElement("td");
  td.textContent = text;
  if (cls) td.className = cls;
  return td;
}
function sparkline(values) {
  const canvas = document.createElement("canvas");
  canvas.width = 120; canvas.height = 24;
  const g = canvas.getContext("2d");
  const top = Math.max(1e-9, ...values);
  g.strokeStyle = "#36c";
  g.beginPath();
  values.forEach((v, i) => {
    const x = i * canvas.width / 120, y = canvas.height - 2 - v / top * (canvas.height - 4);
    if (i === 0) g.moveTo(x, y); else g.lineTo(x, y);
  });
  g.stroke();
  return canvas;
}
async function refresh() {
  let data;
  try {
    data = await (await fetch("status.json", {cache: "no-store"})).json();
  } catch (e) {
    document.getElementById("warnings").innerHTML = "<p>the monitor does not answer</p>";
    return;
  }
  const rows = document.getElementById("rows");
  rows.innerHTML = "";
  const warnings = [];
  for (const p of data.processes) {
    const tr = document.createElement("tr");
    if (p.quiet) {
      tr.className = "quiet";
      warnings.push(p.name + " has not been heard for " + p.age_s.toFixed(0) + " s");
    }
    if (p.lost > 0) warnings.push(p.name + " is missing " + p.lost + " scenes");
    tr.append(cell(p.process), cell(p.name, "name"),
              cell(p.quiet ? "quiet" : states[p.run_state] || "state " + p.run_state),
              cell(p.scenes), cell(p.rate_hz.toFixed(2)));
    const spark = document.createElement("td");
    spark.append(sparkline(p.rate_history));
    tr.append(spark, cell(p.stage_ms.physics.toFixed(0)), cell(p.stage_ms.render.toFixed(0)),
              cell(p.lost), cell(p.resent), cell(p.held_back_s.toFixed(1)), cell(p.refused),
              cell(p.age_s.toFixed(1) + " s ago"));
    rows.append(tr);
  }
  const learners = document.getElementById("learners");
  learners.innerHTML = "";
  document.getElementById("learners-box").style.display = data.learners.length ? "" : "none";
  for (const l of data.learners) {
    const tr = document.createElement("tr");
    if (l.quiet) {
      tr.className = "quiet";
      warnings.push(l.name + " has not been heard for " + l.age_s.toFixed(0) + " s");
    }
    const spark = document.createElement("td");
    spark.append(sparkline(l.loss_history.map(v => v === null ? 0 : v)));
    tr.append(cell(l.process), cell(l.name, "name"),
              cell(l.quiet ? "quiet" : ["training", "ended", "stopped"][l.run_state]),
              cell(l.steps + (l.target_steps ? " / " + l.target_steps : "")),
              cell(l.loss === null ? "-" : l.loss.toFixed(3)), spark, cell(l.scenes_taken),
              cell(l.scenes_per_second.toFixed(2)), cell(l.reuse.toFixed(1)),
              cell(l.age_s.toFixed(1) + " s ago"));
    learners.append(tr);
  }
  document.getElementById("warnings").innerHTML =
      warnings.map(w => "<p>" + w.replace(/[<>&]/g, "") + "</p>").join("");
  document.getElementById("monitor").textContent =
      data.processes.length + " processes; the monitor heard " + data.monitor.status_messages +
      " statuses, refused " + data.monitor.refused + " messages. Metrics for Prometheus: /metrics";
}
refresh();
setInterval(refresh, 2000);
setInterval(() => {
  document.getElementById("sheet").src = "latest.jpg?t=" + Date.now();
}, 4000);
</script>
</body>
</html>
)html";

}  // namespace stackgen
