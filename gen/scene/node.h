#pragma once

// The generator node (docs/design.md, "Processes, nodes and time"): one generator's whole bus life.
// It owns the delivery server (credits, resends, windows), the three-stage pipeline (the next
// piles settle on the physics threads while this one renders, and scenes k - E + 1 .. k are
// encoded on E encoding threads while k + 1 renders), the periodic config, model and status
// messages, and twin detection (another generator with this id on the bus). `stackgen`'s main
// parses flags, builds the config, bus and scene generator, and runs a node.
//
// Where scenes go on the bus, in one hop: Run publishes each scene through
// SceneServer::Publish (STACKGEN_SCENE) and its labels on STACKGEN_LABELS once every reliable
// consumer's window allows it; SceneServer serves resends from its ring or regenerates them
// through SceneGenerator::Generate.

#include <atomic>
#include <cstdint>
#include <memory>

#include "bus/bus.h"
#include "bus/clock.h"
#include "gen/scene/scene_generator.h"

namespace stackgen {

/// What a node does beyond its config (the flags of `stackgen`).
struct GeneratorNodeOptions {
  /// Scenes to publish, seqs first_seq..first_seq+count-1 (or from the resume seq); 0: until
  /// stopped or the last seq of the id layout.
  int64_t count = 0;
  /// The first seq to publish (--first-seq): one task of a cluster job makes seqs
  /// first_seq..first_seq+count-1, the same scenes as one generator making them all.
  int64_t first_seq = 0;
  /// --resume: start at the seq the reliable consumers have stored through (they must credit
  /// within consumer_timeout_s).
  bool resume = false;
  /// A run that ends by itself and that no reliable consumer took, or whose consumer went
  /// silent, is a success anyway (listeners alone were meant).
  bool no_consumer_ok = false;
  /// A reliable consumer silent for this long is no longer waited for (seconds).
  double consumer_timeout_s = 10;
  /// A reliable consumer that credits but receives none of what it lacks for this long ends
  /// the run with an error (SceneServerOptions::stall_timeout_s; seconds).
  double stall_timeout_s = 60;
  /// Encoded scenes kept for resending.
  int ring_size = 64;
  /// Piles settled at once, one world per thread, ahead of the one being rendered (up to four
  /// per thread queued or settled ahead); the scenes are the same for any number (with
  /// physics.pick_sequence one pile settles ahead).
  int physics_threads = 1;
  /// Scenes whose camera model and image encoding run at once, each on its own thread, while
  /// the next renders; they are published in seq order, the same for any number.
  int encode_threads = 1;
  /// A progress line on stderr (a terminal).
  bool progress = false;
  /// Set from a signal handler: the node stops at the next scene, prints its summary and
  /// returns.
  const std::atomic<bool>* stop = nullptr;
  /// The clock of its timers (listening, status period, holding back); null: SteadyClock().
  Clock* clock = nullptr;
};

/// One generator on one bus. Not thread-safe; Run once.
class GeneratorNode {
 public:
  /// `bus` and `generator` must outlive the node. `seed` is the run's base seed and
  /// `config_path` the config's file, as the RunName and the config messages name them.
  GeneratorNode(Bus* bus, SceneGenerator* generator, const LoadedConfig& config, uint64_t seed,
                int generator_id, const GeneratorNodeOptions& options);
  ~GeneratorNode();
  GeneratorNode(const GeneratorNode&) = delete;
  GeneratorNode& operator=(const GeneratorNode&) = delete;

  /// Announces the generator, hears which reliable consumers are there (settles --resume),
  /// publishes the scenes, waits until every reliable consumer stored the last one, and prints
  /// the summary on stdout. Throws std::runtime_error (one line) when another generator with
  /// this id publishes more, a consumer holds another run's scenes, the consumers heard use
  /// another bus key while this bus is open (a keyed one says so and goes on), --resume finds
  /// no consumer, or (without no_consumer_ok) no reliable consumer took the scenes or one went
  /// silent (naming consumers of another key, if heard); and what the scene generator throws.
  /// Warns while it runs when no reliable consumer has been registered for 5 s (unless
  /// no_consumer_ok). Its last status (three times) says whether the run ended or stopped.
  void Run();

 private:
  void RunScenes();
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace stackgen
