// stackgen-monitor's metrics (consumers/monitor/metrics.cc): the Prometheus text of a generator
// and a consumer, label values escaped, quiet processes marked, the table bounded.
#include "consumers/monitor/metrics.h"

#include <cmath>
#include <string>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

namespace stackgen {
namespace {

status Generator() {
  status s{};
  s.header.generator_id = 3;
  s.header.seq = -1;
  s.process = "stackgen";
  s.name = "stackgen/3@host:42";
  s.next_seq = 17;
  s.scenes_held = -1;
  s.scenes = 17;
  s.scenes_rejected = 2;
  s.redraws_unsettled = 2;
  s.scene_bytes = 123456789;
  s.rate_hz = 1.5;
  s.physics_ms = 250;
  s.render_ms = 80;
  s.resent = 4;
  s.held_back_s = 1.25;
  s.reliable_consumers = 1;
  s.refused_forged = 7;
  return s;
}

status Writer() {
  status s{};
  s.header.generator_id = -1;
  s.header.seq = -1;
  s.process = "stackgen-coco";
  s.name = "stackgen-coco@host:/data/\"new\"\\set";
  s.next_seq = -1;
  s.scenes_held = 12;
  s.scenes = 10;
  s.received = 13;
  s.duplicates = 1;
  s.lost = 2;
  return s;
}

// each counter and gauge of a generator and a writer, with the labels that say who it is: the
// generator's id on generators only, a writer's odd name escaped; stage times in seconds
TEST(MonitorMetricsTest, GeneratorAndWriterAsPrometheusText) {
  ProcessTable table;
  table.Update(Generator(), 10.0);
  table.Update(Writer(), 11.0);
  MonitorCounters counters;
  counters.status_messages = 5;
  counters.refused_unsigned = 3;
  const std::string text = PrometheusText(table, counters, 12.0);
  const std::string g = "{process=\"stackgen\",name=\"stackgen/3@host:42\",generator_id=\"3\"";
  const std::string w =
      "{process=\"stackgen-coco\",name=\"stackgen-coco@host:/data/\\\"new\\\"\\\\set\"";
  for (const std::string& line :
       {"stackgen_scenes_total" + g + "} 17",
        "stackgen_redraws_total" + g + ",cause=\"unsettled\"} 2",
        "stackgen_redraws_total" + g + ",cause=\"interpenetrating\"} 0",
        "stackgen_scene_bytes_total" + g + "} 123456789",
        "stackgen_next_seq" + g + "} 17", "stackgen_resent_total" + g + "} 4",
        "stackgen_held_back_seconds_total" + g + "} 1.25",
        "stackgen_stage_seconds" + g + ",stage=\"physics\"} 0.25",
        "stackgen_refused_total" + g + ",reason=\"forged\"} 7",
        "stackgen_last_heard_seconds" + g + "} 2", "stackgen_scenes_total" + w + "} 10",
        "stackgen_scenes_held" + w + "} 12", "stackgen_received_total" + w + "} 13",
        "stackgen_lost" + w + "} 2", std::string("stackgen_monitor_status_messages_total 5"),
        std::string("stackgen_monitor_refused_total{reason=\"unsigned\"} 3"),
        std::string("# TYPE stackgen_scenes_total counter"),
        std::string("# TYPE stackgen_lost gauge")}) {
    EXPECT_NE(text.find(line + "\n"), std::string::npos) << line << "\n" << text;
  }
  // a generator's own families are not a writer's, nor the other way round
  EXPECT_EQ(text.find("stackgen_next_seq" + w), std::string::npos);
  EXPECT_EQ(text.find("stackgen_lost" + g), std::string::npos);
}

// once a generator's config was heard, its run labels its metrics (the writers' RunName)
TEST(MonitorMetricsTest, GeneratorsRunLabelsItsMetrics) {
  ProcessTable table;
  table.Update(Generator(), 0.0);
  table.SetRun(3, "seed 5, config c.pbtxt (sha256 ab)");
  table.SetRun(4, "seed 6, config d.pbtxt (sha256 cd)");
  const std::string text = PrometheusText(table, MonitorCounters{}, 1.0);
  EXPECT_NE(text.find("stackgen_scenes_total{process=\"stackgen\",name=\"stackgen/3@host:42\","
                      "generator_id=\"3\",run=\"seed 5, config c.pbtxt (sha256 ab)\"} 17\n"),
            std::string::npos)
      << text;
  EXPECT_EQ(table.RunOf(7), "");
}

// a process not heard for more than 5 s is quiet, unless it said its run ended, a generator or
// a consumer (a writer that stored its --count); the page's JSON says the same
TEST(MonitorMetricsTest, QuietAfterFiveSecondsUnlessEnded) {
  ProcessTable table;
  status ended = Generator();
  ended.name = "stackgen/4@host:43";
  ended.run_state = 1;
  status writer_ended = Writer();
  writer_ended.name = "stackgen-coco@host:/done";
  writer_ended.run_state = 1;
  table.Update(Generator(), 0.0);
  table.Update(ended, 0.0);
  table.Update(writer_ended, 0.0);
  table.Update(Writer(), 5.5);
  const std::string text = PrometheusText(table, MonitorCounters{}, 6.0);
  EXPECT_NE(text.find("stackgen_quiet{process=\"stackgen\",name=\"stackgen/3@host:42\","
                      "generator_id=\"3\"} 1\n"),
            std::string::npos);
  EXPECT_NE(text.find("stackgen_quiet{process=\"stackgen\",name=\"stackgen/4@host:43\","
                      "generator_id=\"3\"} 0\n"),
            std::string::npos);
  EXPECT_NE(
      text.find("stackgen_quiet{process=\"stackgen-coco\",name=\"stackgen-coco@host:/done\"} 0\n"),
      std::string::npos)
      << text;
  EXPECT_NE(
      text.find("stackgen_run_state{process=\"stackgen-coco\",name=\"stackgen-coco@host:/done\"} "
                "1\n"),
      std::string::npos)
      << text;
  const nlohmann::json json = nlohmann::json::parse(StatusJson(table, MonitorCounters{}, 6.0));
  ASSERT_EQ(json["processes"].size(), 4u);
  int quiet = 0;
  for (const auto& process : json["processes"]) quiet += process["quiet"].get<bool>();
  EXPECT_EQ(quiet, 1);
}

// a learner's progress: its steps, loss (NaN as the format writes it, null in the JSON before the
// first step), scenes, reuse and run state, labelled by process and name
TEST(MonitorMetricsTest, LearnerProgress) {
  ProcessTable table;
  learner_status l{};
  l.header.seq = -1;
  l.header.generator_id = -1;
  l.process = "train-live";
  l.name = "train-live/host:7";
  l.loss = std::nan("");
  table.UpdateLearner(l, 1.0);
  l.steps = 40;
  l.target_steps = 100;
  l.loss = 0.75;
  l.scenes_taken = 12;
  l.scenes_per_second = 1.5;
  l.reuse = 3.25;
  table.UpdateLearner(l, 2.0);
  const std::string labels = "{process=\"train-live\",name=\"train-live/host:7\"}";
  const std::string text = PrometheusText(table, MonitorCounters{}, 3.0);
  for (const std::string& line :
       {"stackgen_learner_steps_total" + labels + " 40",
        "stackgen_learner_target_steps" + labels + " 100",
        "stackgen_learner_loss" + labels + " 0.75",
        "stackgen_learner_scenes_taken_total" + labels + " 12",
        "stackgen_learner_scenes_per_second" + labels + " 1.5",
        "stackgen_learner_reuse" + labels + " 3.25",
        "stackgen_learner_run_state" + labels + " 0",
        "stackgen_learner_last_heard_seconds" + labels + " 1"}) {
    EXPECT_NE(text.find(line + "\n"), std::string::npos) << line << "\n" << text;
  }
  const nlohmann::json json = nlohmann::json::parse(StatusJson(table, MonitorCounters{}, 3.0));
  ASSERT_EQ(json["learners"].size(), 1u);
  EXPECT_EQ(json["learners"][0]["steps"], 40);
  EXPECT_TRUE(json["learners"][0]["loss_history"][0].is_null());
  EXPECT_EQ(json["learners"][0]["loss_history"][1], 0.75);
  l.loss = std::nan("");
  table.UpdateLearner(l, 4.0);
  EXPECT_NE(PrometheusText(table, MonitorCounters{}, 4.0).find("stackgen_learner_loss" + labels +
                                                               " NaN\n"),
            std::string::npos);
}

// a stranger who varies the name cannot grow the table: past 1024 names the one heard least
// recently goes
TEST(MonitorMetricsTest, TableIsBounded) {
  ProcessTable table;
  status s = Writer();
  for (int k = 0; k < 3000; ++k) {
    s.name = "forged/" + std::to_string(k);
    table.Update(s, k);
  }
  EXPECT_EQ(table.entries().size(), ProcessTable::kMaxProcesses);
  EXPECT_EQ(table.entries().count("forged/0"), 0u);
  EXPECT_EQ(table.entries().count("forged/2999"), 1u);
}

}  // namespace
}  // namespace stackgen
