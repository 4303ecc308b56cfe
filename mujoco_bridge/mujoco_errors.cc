#include "mujoco_bridge/mujoco_errors.h"

#include <mujoco/mujoco.h>

#include <csetjmp>
#include <cstdio>
#include <cstdlib>

namespace tetcosim {
namespace {

// the innermost CallCatchingMuJoCoErrors of this thread, or null
thread_local std::jmp_buf* active_jump = nullptr;
// MuJoCo's message, written by the handler just before it jumps (static
// storage: an automatic object changed between setjmp and longjmp would be
// indeterminate after the jump)
thread_local char error_message[1024];

// the handlers set before tetcosim's (null: MuJoCo's defaults)
void (*previous_error)(const char*) = nullptr;
void (*previous_warning)(const char*) = nullptr;

void OnMuJoCoError(const char* message) {
  if (std::jmp_buf* jump = active_jump) {
    std::snprintf(error_message, sizeof(error_message), "%s", message);
    std::longjmp(*jump, 1);
  }
  if (previous_error) {
    previous_error(message);
    return;  // (MuJoCo goes on, as it would with that handler alone)
  }
  std::fprintf(stderr, "MuJoCo error: %s\n", message);
  std::exit(EXIT_FAILURE);
}

void OnMuJoCoWarning(const char* message) {
  if (previous_warning) {
    previous_warning(message);
    return;
  }
  std::fprintf(stderr, "MuJoCo warning: %s\n", message);
}

}  // namespace

void InstallMuJoCoHandlers() {
  static const bool installed = [] {
    previous_error = mju_user_error;
    previous_warning = mju_user_warning;
    mju_user_error = OnMuJoCoError;
    mju_user_warning = OnMuJoCoWarning;
    return true;
  }();
  (void)installed;
}

namespace internal {

void CallCatchingMuJoCoErrors(void (*call)(void*), void* context) {
  InstallMuJoCoHandlers();
  std::jmp_buf jump;
  std::jmp_buf* const outer = active_jump;
  active_jump = &jump;
  if (setjmp(jump) == 0) {
    try {
      call(context);
    } catch (...) {
      active_jump = outer;  // (an exception of the call's own, or a nested call's)
      throw;
    }
    active_jump = outer;
    return;
  }
  // MuJoCo's handler jumped here: its frames between are abandoned
  active_jump = outer;
  throw MuJoCoError(error_message);
}

}  // namespace internal
}  // namespace tetcosim
