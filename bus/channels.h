#pragma once

#include <cstdint>

namespace stackgen {

/// Whole scenes: labels plus colour, depth and instance images (stackgen::scene).
inline constexpr const char* kSceneChannel = "STACKGEN_SCENE";
/// Labels only, small (stackgen::labels).
inline constexpr const char* kLabelsChannel = "STACKGEN_LABELS";
/// Counters and rates of every process, about 1 Hz (stackgen::status).
inline constexpr const char* kStatusChannel = "STACKGEN_STATUS";
/// The generator config in force, latched, about 1 Hz (stackgen::config_text).
inline constexpr const char* kConfigChannel = "STACKGEN_CONFIG";
/// The 3D model of each labelled class, latched, about every 5 s and at the end of a run
/// (stackgen::model).
inline constexpr const char* kModelChannel = "STACKGEN_MODEL";
/// A learner's progress, about 1 Hz (stackgen::learner_status; stackgen.LearnerStatus).
inline constexpr const char* kLearnerChannel = "STACKGEN_LEARNER";

/// Flow control from reliable consumers to generators (stackgen::credit).
inline constexpr const char* kCreditChannel = "STACKGEN_CREDIT";
/// Requests for missed scenes, from consumers to a generator (stackgen::resend_request).
inline constexpr const char* kResendChannel = "STACKGEN_RESEND";

/// The bus key's liveness check: challenges and answers between every two keyed processes
/// (stackgen::liveness; bus/liveness.h). Sent and heard by the Bus itself.
inline constexpr const char* kLivenessChannel = "STACKGEN_LIVENESS";
/// Asks for the fragments of a message heard only in part (stackgen::fragment_repair;
/// bus/udpm.h). Sent and heard by the Bus itself.
inline constexpr const char* kRepairChannel = "STACKGEN_REPAIR";

/// status.run_state: running; ended (a generator: every scene published and stored; a consumer:
/// what it was asked for taken, or its stream ended); stopped before its end (a signal, an
/// error, a consumer's timeout).
inline constexpr int8_t kRunRunning = 0;
inline constexpr int8_t kRunEnded = 1;
inline constexpr int8_t kRunStopped = 2;

}  // namespace stackgen
