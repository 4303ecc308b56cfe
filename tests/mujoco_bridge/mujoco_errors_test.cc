#include "mujoco_bridge/mujoco_errors.h"

#include <fcntl.h>
#include <gtest/gtest.h>
#include <mujoco/mujoco.h>
#include <unistd.h>

#include <filesystem>
#include <string>
#include <thread>
#include <vector>

#include "tests/mujoco_bridge/temp_dir.h"

namespace tetcosim {
namespace {

// MuJoCo's message from a call, or "" when it returned
template <typename Call>
std::string ErrorFrom(Call&& call) {
  try {
    CallMuJoCo(call);
  } catch (const MuJoCoError& e) {
    return e.what();
  }
  return "";
}

TEST(MuJoCoErrors, AFatalErrorInACallIsThrownWithMuJoCosMessage) {
  bool went_on = false;
  EXPECT_EQ(ErrorFrom([&] {
              mju_error("test error 1");
              went_on = true;
            }),
            "test error 1");
  EXPECT_FALSE(went_on) << "MuJoCo went on after its error";
  // a call without an error returns as usual
  EXPECT_EQ(ErrorFrom([&] { went_on = true; }), "");
  EXPECT_TRUE(went_on);
}

// A box resting on a plane: a step needs MuJoCo's stack for its contacts.
// With the stack full the step fails; once the data is reset it steps on.
TEST(MuJoCoErrors, AStepBeyondMuJoCosStackThrowsAndTheDataStepsOnOnceReset) {
  TempDir dir("tetcosim_mujoco_errors");
  const std::string path = dir.Write("box.xml", R"(<mujoco>
  <worldbody>
    <geom type="plane" size="1 1 0.1"/>
    <body pos="0 0 0.099"><freejoint/><geom type="box" size="0.1 0.1 0.1"/></body>
  </worldbody>
</mujoco>)");
  char error[1000] = "";
  mjModel* m = mj_loadXML(path.c_str(), nullptr, error, sizeof(error));
  ASSERT_NE(m, nullptr) << error;
  mjData* d = mj_makeData(m);
  CallMuJoCo([&] { mj_step(m, d); });
  ASSERT_GT(d->ncon, 0);
  const double time = d->time;
  d->pstack = m->nstack - 10;  // ten numbers left
  EXPECT_EQ(ErrorFrom([&] { mj_step(m, d); }), "Stack overflow");
  mj_resetData(m, d);
  EXPECT_EQ(d->pstack, 0);
  EXPECT_EQ(ErrorFrom([&] { mj_step(m, d); }), "");
  EXPECT_EQ(d->time, time);  // one step from the start again
  mj_deleteData(d);
  mj_deleteModel(m);
}

TEST(MuJoCoErrors, CallsNestAndAnExceptionLeavesTheOuterCallInCharge) {
  std::string inner;
  EXPECT_EQ(ErrorFrom([&] {
              inner = ErrorFrom([] { mju_error("inner"); });
              mju_error("outer");
            }),
            "outer");
  EXPECT_EQ(inner, "inner");
  // an exception of the call's own passes through, and the call that
  // encloses it catches MuJoCo's next error
  EXPECT_EQ(ErrorFrom([&] {
              try {
                CallMuJoCo([] { throw std::runtime_error("the call's own"); });
              } catch (const std::runtime_error&) {
              }
              mju_error("after the exception");
            }),
            "after the exception");
}

TEST(MuJoCoErrors, EachThreadCatchesItsOwnErrors) {
  std::vector<std::string> mismatches(2);
  auto run = [&](int thread) {
    const std::string mine = "thread " + std::to_string(thread);
    for (int i = 0; i < 2000; ++i) {
      const std::string got = ErrorFrom([&] { mju_error(mine.c_str()); });
      if (got != mine && mismatches[thread].empty()) mismatches[thread] = got;
    }
  };
  std::thread first(run, 0);
  std::thread second(run, 1);
  first.join();
  second.join();
  EXPECT_EQ(mismatches[0], "");
  EXPECT_EQ(mismatches[1], "");
}

// Outside any call (or after a call left by an exception) an error ends the
// process at once with the message and status 1, as MuJoCo's own handler
// would, but without waiting for Enter: here standard input is a pipe that
// never ends, where MuJoCo's handler waited until the alarm.
TEST(MuJoCoErrorsDeathTest, AnErrorOutsideACallExitsAtOnceWithTheMessage) {
  GTEST_FLAG_SET(death_test_style, "threadsafe");
  auto error_with_stdin_open = [](bool after_exception) {
    int fds[2];
    if (pipe(fds) != 0 || dup2(fds[0], STDIN_FILENO) < 0) std::_Exit(3);
    alarm(20);
    InstallMuJoCoHandlers();
    if (after_exception) {
      try {
        CallMuJoCo([] { throw std::runtime_error("the call's own"); });
      } catch (const std::runtime_error&) {
      }
    }
    mju_error("outside any call");
  };
  EXPECT_EXIT(error_with_stdin_open(false), testing::ExitedWithCode(1),
              "MuJoCo error: outside any call");
  EXPECT_EXIT(error_with_stdin_open(true), testing::ExitedWithCode(1),
              "MuJoCo error: outside any call");
}

// MuJoCo 2.2.2 wrote its warnings to standard output and appended them to
// MUJOCO_LOG.TXT in the working directory.
TEST(MuJoCoErrors, WarningsGoToStandardErrorAndNoLogFile) {
  TempDir dir("tetcosim_mujoco_warnings");
  const std::filesystem::path before = std::filesystem::current_path();
  std::filesystem::current_path(dir.path());
  InstallMuJoCoHandlers();
  testing::internal::CaptureStdout();
  testing::internal::CaptureStderr();
  mju_warning("test warning");
  const std::string err = testing::internal::GetCapturedStderr();
  const std::string out = testing::internal::GetCapturedStdout();
  std::filesystem::current_path(before);
  EXPECT_NE(err.find("MuJoCo warning: test warning"), std::string::npos) << err;
  EXPECT_EQ(out, "");
  EXPECT_FALSE(std::filesystem::exists(dir.path() / "MUJOCO_LOG.TXT"));
}

}  // namespace
}  // namespace tetcosim
