#include "consumers/monitor/metrics.h"

#include <cmath>
#include <cstdio>
#include <functional>
#include <tuple>
#include <utility>
#include <vector>

#include <nlohmann/json.hpp>

namespace stackgen {

namespace {

// a label value as the exposition format writes it: \\, \" and \n escaped
std::string Escaped(const std::string& value) {
  std::string out;
  for (const char c : value) {
    if (c == '\\') {
      out += "\\\\";
    } else if (c == '"') {
      out += "\\\"";
    } else if (c == '\n') {
      out += "\\n";
    } else {
      out += c;
    }
  }
  return out;
}

// a number as the format writes it: integers whole, others with 17 significant digits, NaN and
// the infinities by their names
std::string Value(double value) {
  if (std::isnan(value)) return "NaN";
  if (std::isinf(value)) return value > 0 ? "+Inf" : "-Inf";
  char text[64];
  if (value == static_cast<double>(static_cast<int64_t>(value)) && value < 9e15 && value > -9e15) {
    std::snprintf(text, sizeof(text), "%lld", static_cast<long long>(value));
  } else {
    std::snprintf(text, sizeof(text), "%.17g", value);
  }
  return text;
}

// a process's labels (a generator's run from `table` when heard), `extra` (already written,
// e.g. stage="render") after them
std::string Labels(const ProcessTable& table, const status& s, const std::string& extra = "") {
  std::string labels = "process=\"" + Escaped(s.process) + "\",name=\"" + Escaped(s.name) + "\"";
  if (s.header.generator_id >= 0) {
    labels += ",generator_id=\"" + std::to_string(s.header.generator_id) + "\"";
    const std::string run = table.RunOf(s.header.generator_id);
    if (!run.empty()) labels += ",run=\"" + Escaped(run) + "\"";
  }
  if (!extra.empty()) labels += "," + extra;
  return "{" + labels + "}";
}

// one metric family: its HELP, TYPE and a sample per process
struct Family {
  const char* name;
  const char* type;  // counter or gauge
  const char* help;
  std::function<double(const ProcessTable::Entry&, double now_s)> value;
  bool generators_only = false;
  bool consumers_only = false;
};

bool IsGenerator(const status& s) { return s.header.generator_id >= 0; }

}  // namespace

void ProcessTable::Update(const status& message, double now_s) {
  if (entries_.size() >= kMaxProcesses && entries_.count(message.name) == 0) {
    auto oldest = entries_.begin();
    for (auto it = entries_.begin(); it != entries_.end(); ++it) {
      if (it->second.heard_s < oldest->second.heard_s) oldest = it;
    }
    entries_.erase(oldest);
  }
  Entry& entry = entries_[message.name];
  entry.latest = message;
  entry.heard_s = now_s;
  entry.rate_hz.push_back(message.rate_hz);
  if (entry.rate_hz.size() > kRateHistory) entry.rate_hz.pop_front();
}

void ProcessTable::UpdateLearner(const learner_status& message, double now_s) {
  if (learners_.size() >= kMaxProcesses && learners_.count(message.name) == 0) {
    auto oldest = learners_.begin();
    for (auto it = learners_.begin(); it != learners_.end(); ++it) {
      if (it->second.heard_s < oldest->second.heard_s) oldest = it;
    }
    learners_.erase(oldest);
  }
  Learner& learner = learners_[message.name];
  learner.latest = message;
  learner.heard_s = now_s;
  learner.loss.push_back(message.loss);
  if (learner.loss.size() > kRateHistory) learner.loss.pop_front();
}

void ProcessTable::SetRun(int32_t generator_id, const std::string& run) {
  if (runs_.size() >= kMaxProcesses && runs_.count(generator_id) == 0) return;
  runs_[generator_id] = run;
}

std::string ProcessTable::RunOf(int32_t generator_id) const {
  const auto found = runs_.find(generator_id);
  return found == runs_.end() ? std::string() : found->second;
}

std::string PrometheusText(const ProcessTable& table, const MonitorCounters& counters,
                           double now_s) {
  using E = ProcessTable::Entry;
  const std::vector<Family> families = {
      {"stackgen_scenes_total", "counter",
       "Scenes published for the first time (generator) or stored (consumer) since it started.",
       [](const E& e, double) { return static_cast<double>(e.latest.scenes); }},
      {"stackgen_scenes_per_second", "gauge",
       "Scenes per second over the process's last status period.",
       [](const E& e, double) { return e.latest.rate_hz; }},
      {"stackgen_scene_bytes_total", "counter",
       "Bytes of scene messages the generator published for the first time.",
       [](const E& e, double) { return static_cast<double>(e.latest.scene_bytes); }, true},
      {"stackgen_next_seq", "gauge", "The next seq the generator will publish.",
       [](const E& e, double) { return static_cast<double>(e.latest.next_seq); }, true},
      {"stackgen_resent_total", "counter", "Scenes published again from the ring of recent ones.",
       [](const E& e, double) { return static_cast<double>(e.latest.resent); }, true},
      {"stackgen_regenerated_total", "counter",
       "Scenes older than the ring made again from their seed and published again.",
       [](const E& e, double) { return static_cast<double>(e.latest.regenerated); }, true},
      {"stackgen_reliable_consumers", "gauge", "Reliable consumers registered with the generator.",
       [](const E& e, double) { return static_cast<double>(e.latest.reliable_consumers); }, true},
      {"stackgen_held_back_seconds_total", "counter",
       "Seconds the generator was held back by its reliable consumers' credits.",
       [](const E& e, double) { return e.latest.held_back_s; }, true},
      {"stackgen_scenes_held", "gauge",
       "Scenes the consumer holds: a writer's dataset, a learner's scenes handed over.",
       [](const E& e, double) { return static_cast<double>(e.latest.scenes_held); }, false, true},
      {"stackgen_received_total", "counter", "Scene messages received, duplicates included.",
       [](const E& e, double) { return static_cast<double>(e.latest.received); }, false, true},
      {"stackgen_duplicates_total", "counter", "Scenes received twice or more (stored once).",
       [](const E& e, double) { return static_cast<double>(e.latest.duplicates); }, false, true},
      {"stackgen_lost", "gauge",
       "Seqs missing now below the highest received (lost unless a resend fills them).",
       [](const E& e, double) { return static_cast<double>(e.latest.lost); }, false, true},
      {"stackgen_reasked_total", "counter", "Seqs asked for again on STACKGEN_RESEND.",
       [](const E& e, double) { return static_cast<double>(e.latest.reasked); }, false, true},
      {"stackgen_bad_messages_total", "counter",
       "Messages on its channels that did not decode or were invalid, skipped.",
       [](const E& e, double) { return static_cast<double>(e.latest.bad_messages); }},
      {"stackgen_fault_dropped_total", "counter", "Messages dropped on purpose (--fault-drop).",
       [](const E& e, double) { return static_cast<double>(e.latest.fault_dropped); }},
      {"stackgen_run_state", "gauge",
       "Where the process's run stands: 0 running, 1 ended (a generator: all stored; a "
       "consumer: what it was asked for), 2 stopped early.",
       [](const E& e, double) { return static_cast<double>(e.latest.run_state); }},
      {"stackgen_last_heard_seconds", "gauge", "Seconds since the process's last status.",
       [](const E& e, double now) { return now - e.heard_s; }},
      {"stackgen_quiet", "gauge",
       "1 when the process has not been heard for 5 s and did not say it ended, else 0.",
       [](const E& e, double now) {
         return now - e.heard_s > kQuietAfterS && e.latest.run_state == 0 ? 1.0 : 0.0;
       }},
  };
  std::string text;
  for (const Family& family : families) {
    text += std::string("# HELP ") + family.name + " " + family.help + "\n";
    text += std::string("# TYPE ") + family.name + " " + family.type + "\n";
    for (const auto& [name, entry] : table.entries()) {
      const bool generator = IsGenerator(entry.latest);
      if ((family.generators_only && !generator) || (family.consumers_only && generator)) continue;
      text += family.name + Labels(table, entry.latest) + " " +
              Value(family.value(entry, now_s)) + "\n";
    }
  }
  // the stage times, one family with a label per stage
  text +=
      "# HELP stackgen_stage_seconds Mean seconds per scene of each stage of the generator "
      "since it started.\n# TYPE stackgen_stage_seconds gauge\n";
  for (const auto& [name, entry] : table.entries()) {
    if (!IsGenerator(entry.latest)) continue;
    const std::pair<const char*, double> stages[] = {{"physics", entry.latest.physics_ms},
                                                    {"render", entry.latest.render_ms},
                                                    {"annotate", entry.latest.annotate_ms},
                                                    {"publish", entry.latest.publish_ms}};
    for (const auto& [stage, ms] : stages) {
      const std::string labels =
          Labels(table, entry.latest, "stage=\"" + std::string(stage) + "\"");
      text += "stackgen_stage_seconds" + labels + " " + Value(ms / 1000) + "\n";
    }
  }
  // the generators' redraws, by cause
  text +=
      "# HELP stackgen_redraws_total Drops the generator redrew because they failed a check, by "
      "cause.\n# TYPE stackgen_redraws_total counter\n";
  for (const auto& [name, entry] : table.entries()) {
    if (!IsGenerator(entry.latest)) continue;
    const status& s = entry.latest;
    const std::pair<const char*, int64_t> causes[] = {{"unsettled", s.redraws_unsettled},
                                                     {"outside", s.redraws_outside},
                                                     {"interpenetrating", s.redraws_penetrating}};
    for (const auto& [cause, count] : causes) {
      text += "stackgen_redraws_total" + Labels(table, s, "cause=\"" + std::string(cause) + "\"") +
              " " + Value(static_cast<double>(count)) + "\n";
    }
  }
  // messages each process refused, by reason
  text +=
      "# HELP stackgen_refused_total Messages refused by the bus key check, by reason.\n"
      "# TYPE stackgen_refused_total counter\n";
  for (const auto& [name, entry] : table.entries()) {
    const status& s = entry.latest;
    const std::pair<const char*, int64_t> reasons[] = {{"unsigned", s.refused_unsigned},
                                                      {"forged", s.refused_forged},
                                                      {"replayed", s.refused_replayed},
                                                      {"relayed", s.refused_relayed}};
    for (const auto& [reason, count] : reasons) {
      text += "stackgen_refused_total" +
              Labels(table, s, "reason=\"" + std::string(reason) + "\"") + " " +
              Value(static_cast<double>(count)) + "\n";
    }
  }
  // the learners
  using L = ProcessTable::Learner;
  const std::vector<std::tuple<const char*, const char*, const char*,
                               std::function<double(const L&)>>>
      learner_families = {
          {"stackgen_learner_steps_total", "counter", "Optimiser steps the learner took.",
           [](const L& l) { return static_cast<double>(l.latest.steps); }},
          {"stackgen_learner_target_steps", "gauge", "Steps the learner will take (0: unknown).",
           [](const L& l) { return static_cast<double>(l.latest.target_steps); }},
          {"stackgen_learner_loss", "gauge", "The training loss of the learner's last step.",
           [](const L& l) { return l.latest.loss; }},
          {"stackgen_learner_scenes_taken_total", "counter", "Scenes the learner took.",
           [](const L& l) { return static_cast<double>(l.latest.scenes_taken); }},
          {"stackgen_learner_scenes_per_second", "gauge", "Scenes the learner takes per second.",
           [](const L& l) { return l.latest.scenes_per_second; }},
          {"stackgen_learner_reuse", "gauge", "Training samples per scene taken.",
           [](const L& l) { return l.latest.reuse; }},
          {"stackgen_learner_run_state", "gauge",
           "Where the learner's run stands: 0 training, 1 ended, 2 stopped early.",
           [](const L& l) { return static_cast<double>(l.latest.run_state); }},
      };
  for (const auto& [name, type, help, value] : learner_families) {
    text += std::string("# HELP ") + name + " " + help + "\n# TYPE " + name + " " + type + "\n";
    for (const auto& [learner_name, learner] : table.learners()) {
      const std::string labels = "{process=\"" + Escaped(learner.latest.process) + "\",name=\"" +
                                 Escaped(learner.latest.name) + "\"}";
      text += std::string(name) + labels + " " + Value(value(learner)) + "\n";
    }
  }
  text +=
      "# HELP stackgen_learner_last_heard_seconds Seconds since the learner's last report.\n"
      "# TYPE stackgen_learner_last_heard_seconds gauge\n";
  for (const auto& [learner_name, learner] : table.learners()) {
    text += "stackgen_learner_last_heard_seconds{process=\"" + Escaped(learner.latest.process) +
            "\",name=\"" + Escaped(learner.latest.name) + "\"} " +
            Value(now_s - learner.heard_s) + "\n";
  }

  // the monitor's own
  text +=
      "# HELP stackgen_monitor_processes Processes the monitor has heard.\n"
      "# TYPE stackgen_monitor_processes gauge\nstackgen_monitor_processes " +
      Value(static_cast<double>(table.entries().size())) +
      "\n# HELP stackgen_monitor_status_messages_total Statuses the monitor heard.\n"
      "# TYPE stackgen_monitor_status_messages_total counter\n"
      "stackgen_monitor_status_messages_total " +
      Value(static_cast<double>(counters.status_messages)) +
      "\n# HELP stackgen_monitor_bad_messages_total Messages the monitor could not decode.\n"
      "# TYPE stackgen_monitor_bad_messages_total counter\n"
      "stackgen_monitor_bad_messages_total " +
      Value(static_cast<double>(counters.bad_messages)) +
      "\n# HELP stackgen_monitor_refused_total Messages the monitor's bus key check refused, by "
      "reason.\n# TYPE stackgen_monitor_refused_total counter\n";
  const std::pair<const char*, int64_t> own[] = {{"unsigned", counters.refused_unsigned},
                                                {"forged", counters.refused_forged},
                                                {"replayed", counters.refused_replayed},
                                                {"relayed", counters.refused_relayed}};
  for (const auto& [reason, count] : own) {
    text += "stackgen_monitor_refused_total{reason=\"" + std::string(reason) + "\"} " +
            Value(static_cast<double>(count)) + "\n";
  }
  return text;
}

std::string StatusJson(const ProcessTable& table, const MonitorCounters& counters, double now_s) {
  nlohmann::json processes = nlohmann::json::array();
  for (const auto& [name, entry] : table.entries()) {
    const status& s = entry.latest;
    const double age = now_s - entry.heard_s;
    nlohmann::json process = {
        {"process", s.process},
        {"name", s.name},
        {"generator_id", s.header.generator_id},
        {"scenes", s.scenes},
        {"rate_hz", s.rate_hz},
        {"rate_history", std::vector<double>(entry.rate_hz.begin(), entry.rate_hz.end())},
        {"stage_ms",
         {{"physics", s.physics_ms},
          {"render", s.render_ms},
          {"annotate", s.annotate_ms},
          {"publish", s.publish_ms}}},
        {"lost", s.lost},
        {"resent", s.resent},
        {"held_back_s", s.held_back_s},
        {"refused", s.refused_unsigned + s.refused_forged + s.refused_replayed + s.refused_relayed},
        {"run_state", s.run_state},
        {"age_s", age},
        {"quiet", age > kQuietAfterS && s.run_state == 0}};
    processes.push_back(std::move(process));
  }
  nlohmann::json learners = nlohmann::json::array();
  for (const auto& [name, learner] : table.learners()) {
    const learner_status& l = learner.latest;
    const double age = now_s - learner.heard_s;
    // (JSON has no NaN: a loss not known yet is null)
    const auto number = [](double v) { return std::isfinite(v) ? nlohmann::json(v) : nullptr; };
    nlohmann::json history = nlohmann::json::array();
    for (const double loss : learner.loss) history.push_back(number(loss));
    learners.push_back({{"process", l.process},
                        {"name", l.name},
                        {"steps", l.steps},
                        {"target_steps", l.target_steps},
                        {"loss", number(l.loss)},
                        {"loss_history", std::move(history)},
                        {"scenes_taken", l.scenes_taken},
                        {"scenes_per_second", l.scenes_per_second},
                        {"reuse", l.reuse},
                        {"run_state", l.run_state},
                        {"age_s", age},
                        {"quiet", age > kQuietAfterS && l.run_state == 0}});
  }
  const nlohmann::json out = {
      {"processes", std::move(processes)},
      {"learners", std::move(learners)},
      {"monitor",
       {{"status_messages", counters.status_messages},
        {"bad_messages", counters.bad_messages},
        {"refused", counters.refused_unsigned + counters.refused_forged +
                        counters.refused_replayed + counters.refused_relayed}}}};
  return out.dump();
}

}  // namespace stackgen
