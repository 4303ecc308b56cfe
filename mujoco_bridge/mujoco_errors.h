#pragma once

// MuJoCo's fatal errors as exceptions, and its warnings on standard error.
//
// MuJoCo 2.2.2 reports a fatal error (its stack or heap exhausted, a render
// context it cannot make, a bad argument) through mju_error, which, with no
// handler set, prints "Press Enter to exit", waits for a key and exits the
// process: a rollout in a terminal hung there, and one without a terminal
// ended with its summary unwritten. Its warnings went to standard output and
// to MUJOCO_LOG.TXT in the working directory.
//
// tetcosim sets handlers for both, once per process. A fatal error inside
// CallMuJoCo jumps back to that call, which throws MuJoCoError; World::Step
// turns it into a status (StepStatus::kFailed) and World::Load into an Error
// naming the scene. A fatal error outside CallMuJoCo (a program's own MuJoCo
// calls) goes to the handler the program set before tetcosim's, if any, and
// otherwise is printed to standard error before the process exits with
// status 1, as MuJoCo would, without waiting. Warnings go to the handler set
// before, if any, and otherwise to standard error.

#include <string>
#include <type_traits>

#include "mesh/error.h"

namespace tetcosim {

// A fatal error MuJoCo raised inside CallMuJoCo; what() is MuJoCo's message.
// The mjData the call worked on is left mid-computation (MuJoCo's stack
// marked in use, fields half written): reset or delete it before stepping
// it again.
class MuJoCoError : public Error {
 public:
  explicit MuJoCoError(const std::string& message) : Error(message) {}
};

// Sets tetcosim's handlers for mju_error and mju_warning (the first call in
// the process; later calls do nothing). CallMuJoCo calls it.
void InstallMuJoCoHandlers();

namespace internal {
// Calls call(context) with MuJoCo's fatal errors in this thread jumping back
// here; throws MuJoCoError after one.
void CallCatchingMuJoCoErrors(void (*call)(void*), void* context);
}  // namespace internal

// Runs `call` (a lambda that calls MuJoCo's C functions and nothing that
// owns a resource: the error handler leaves it by longjmp, which skips
// destructors) and throws MuJoCoError if MuJoCo raised a fatal error in it.
// Calls may nest, and each thread has its own.
template <typename Call>
void CallMuJoCo(Call&& call) {
  using CallType = std::remove_reference_t<Call>;
  static_assert(std::is_trivially_destructible_v<CallType>,
                "CallMuJoCo: the call must own nothing (it may be left by longjmp)");
  internal::CallCatchingMuJoCoErrors([](void* context) { (*static_cast<CallType*>(context))(); },
                                     const_cast<std::remove_const_t<CallType>*>(&call));
}

}  // namespace tetcosim
