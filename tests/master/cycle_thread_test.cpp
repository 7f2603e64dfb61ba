// The master's threads and its cycle thread's realtime setup: the cycle (bus) thread is named
// apart from the control thread (read back from /proc/self/task/*/comm, as ps and perf show
// them), a configuration that asks for nothing changes nothing, what was asked is held while the
// session runs and released when it stops, and a refusal is reported with its reason.
#include "master/cycle_thread.hpp"

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <fstream>
#include <string>
#include <vector>

#include <dirent.h>
#include <gtest/gtest.h>
#include <linux/capability.h>
#include <sched.h>
#include <sys/resource.h>
#include <sys/syscall.h>
#include <unistd.h>

#include <ecat/master/master.hpp>

#include "master/master_test_support.hpp"

namespace ecat::master {
namespace {

using namespace std::chrono_literals;

constexpr const char* kRing = test::kTerminalRing;

struct TaskInfo {
  int tid = 0;
  std::string name;
};

std::vector<TaskInfo> threads() {
  std::vector<TaskInfo> out;
  DIR* dir = ::opendir("/proc/self/task");
  if (dir == nullptr) return out;
  while (const dirent* e = ::readdir(dir)) {
    if (e->d_name[0] == '.') continue;
    std::ifstream comm(std::string("/proc/self/task/") + e->d_name + "/comm");
    std::string name;
    std::getline(comm, name);
    out.push_back({std::atoi(e->d_name), name});
  }
  ::closedir(dir);
  return out;
}

std::size_t named(const std::string& name) {
  const auto all = threads();
  return static_cast<std::size_t>(
      std::count_if(all.begin(), all.end(), [&](const TaskInfo& t) { return t.name == name; }));
}

int tid_of(const std::string& name) {
  for (const auto& t : threads()) {
    if (t.name == name) return t.tid;
  }
  return 0;
}

// Whether this process has /dev/cpu_dma_latency open.
bool holds_dma_latency() {
  DIR* dir = ::opendir("/proc/self/fd");
  if (dir == nullptr) return false;
  bool found = false;
  while (const dirent* e = ::readdir(dir)) {
    char target[256] = {};
    const auto path = std::string("/proc/self/fd/") + e->d_name;
    const auto n = ::readlink(path.c_str(), target, sizeof target - 1);
    if (n > 0 && std::string(target, static_cast<std::size_t>(n)) == "/dev/cpu_dma_latency") {
      found = true;
    }
  }
  ::closedir(dir);
  return found;
}

// VmLck of this process, in kB.
long locked_kb() {
  std::ifstream status("/proc/self/status");
  std::string line;
  while (std::getline(status, line)) {
    if (line.rfind("VmLck:", 0) == 0) return std::atol(line.c_str() + 6);
  }
  return -1;
}

MasterConfig config() {
  return test::quick_config();
}

class CycleThreadTest : public ::testing::Test {
 protected:
  std::unique_ptr<link::Link> serve() {
    servers_.push_back(test::make_sim_server(kRing));
    EXPECT_TRUE(servers_.back());
    auto l = servers_.back()->serve_memory();
    EXPECT_TRUE(l) << l.error().describe();
    return std::move(*l);
  }
  std::vector<std::unique_ptr<sim::SimServer>> servers_;
};

TEST_F(CycleThreadTest, CycleAndControlThreadsHaveTheirOwnNames) {
  Master first(config());
  EXPECT_EQ(named("ecat-control"), 1u);
  EXPECT_EQ(named("ecat-cycle"), 0u);  // no session yet
  ASSERT_TRUE(first.start(serve()));
  ASSERT_TRUE(first.await_operational(10s));
  EXPECT_EQ(named("ecat-cycle"), 1u);
  {
    // A second master alive at the same time: numbered, so ps and perf tell them apart.
    Master second(config());
    ASSERT_TRUE(second.start(serve()));
    ASSERT_TRUE(second.await_operational(10s));
    EXPECT_EQ(named("ecat-control-2"), 1u);
    EXPECT_EQ(named("ecat-cycle-2"), 1u);
    EXPECT_EQ(named("ecat-cycle"), 1u);
    ASSERT_TRUE(second.stop());
    EXPECT_EQ(named("ecat-cycle-2"), 0u);
  }
  EXPECT_EQ(named("ecat-control-2"), 0u);
  ASSERT_TRUE(first.stop());
  EXPECT_EQ(named("ecat-cycle"), 0u);
  EXPECT_EQ(named("ecat-control"), 1u);  // the control thread lives as long as the Master
  // The number is free again: the next master alive beside `first` is "-2" again.
  Master again(config());
  EXPECT_EQ(named("ecat-control-2"), 1u);
}

TEST_F(CycleThreadTest, AConfigurationThatAsksNothingChangesNothing) {
  const long locked_before = locked_kb();
  Master master(config());
  ASSERT_TRUE(master.start(serve()));
  ASSERT_TRUE(master.await_operational(10s));
  EXPECT_EQ(master.status().cycle_thread, "");
  const int tid = tid_of("ecat-cycle");
  ASSERT_NE(tid, 0);
  EXPECT_EQ(::sched_getscheduler(tid), SCHED_OTHER);
  EXPECT_FALSE(holds_dma_latency());
  EXPECT_EQ(locked_kb(), locked_before);
  ASSERT_TRUE(master.stop());
}

#if defined(__SANITIZE_ADDRESS__)
#define ECAT_TEST_ASAN 1
#elif defined(__has_feature)
#if __has_feature(address_sanitizer)
#define ECAT_TEST_ASAN 1
#endif
#endif

TEST_F(CycleThreadTest, WhatWasAskedIsHeldWhileTheSessionRuns) {
#ifdef ECAT_TEST_ASAN
  GTEST_SKIP() << "mlockall would lock the sanitizer's shadow memory";
#else
  ASSERT_EQ(locked_kb(), 0) << "something else in this process locked memory";
  auto c = config();
  c.cycle_thread.cpu_dma_latency_us = 0;
  c.cycle_thread.lock_memory = true;
  Master master(c);
  ASSERT_TRUE(master.start(serve()));
  ASSERT_TRUE(master.await_operational(10s));
  const auto report = master.status().cycle_thread;
  // Root may or may not have /dev/cpu_dma_latency (containers); either way the report says.
  const bool held = report.starts_with("cpu_dma_latency 0 us: held; ");
  EXPECT_TRUE(held || report.starts_with("cpu_dma_latency 0 us: refused (/dev/cpu_dma_latency: "))
      << report;
  EXPECT_EQ(holds_dma_latency(), held);
  const bool locked = report.ends_with("memory: locked, 256 KiB of stack pre-faulted");
  EXPECT_TRUE(locked || report.find("memory: not locked (mlockall: ") != std::string::npos)
      << report;
  if (locked) {
    EXPECT_GT(locked_kb(), 0);
  }
  ASSERT_TRUE(master.stop());
  // Released with the session.
  EXPECT_FALSE(holds_dma_latency());
  EXPECT_EQ(locked_kb(), 0);
#endif
}

TEST(CycleThreadSetup, ARefusedCpuDmaLatencyIsReportedWithItsReason) {
  CycleThreadOptions options;
  options.cpu_dma_latency_us = 0;
  CycleThreadHolds holds;
  EXPECT_EQ(apply_cycle_thread(options, holds, "/nonexistent/cpu_dma_latency"),
            "cpu_dma_latency 0 us: refused (/nonexistent/cpu_dma_latency: No such file or "
            "directory)");
  EXPECT_EQ(holds.dma_latency_fd, -1);
  EXPECT_EQ(apply_cycle_thread(CycleThreadOptions{}, holds), "");
}

// Without the privileges (a child process that dropped CAP_SYS_NICE and CAP_IPC_LOCK and has
// no realtime or memory-lock allowance): each refusal is reported, the thread runs on.
// The child's part: drop the privileges, ask, print the report, exit 0 unless memory was locked.
[[noreturn]] void ask_without_privilege() {
  __user_cap_header_struct header{_LINUX_CAPABILITY_VERSION_3, 0};
  __user_cap_data_struct data[2] = {};
  if (syscall(SYS_capget, &header, data) != 0) _exit(3);
  for (const int cap : {CAP_SYS_NICE, CAP_IPC_LOCK}) {
    data[cap / 32].effective &= ~(1u << (cap % 32));
    data[cap / 32].permitted &= ~(1u << (cap % 32));
  }
  if (syscall(SYS_capset, &header, data) != 0) _exit(4);
  const rlimit none{0, 0};
  setrlimit(RLIMIT_RTPRIO, &none);
  setrlimit(RLIMIT_MEMLOCK, &none);
  CycleThreadOptions options;
  options.fifo_priority = 10;
  options.lock_memory = true;
  CycleThreadHolds holds;
  const auto report = apply_cycle_thread(options, holds);
  std::fprintf(stderr, "%s\n", report.c_str());
  std::fflush(stderr);
  _exit(holds.memory_locked ? 5 : 0);
}

// Without the privileges (a child process that dropped CAP_SYS_NICE and CAP_IPC_LOCK and has
// no realtime or memory-lock allowance): each refusal is reported, the thread runs on.
TEST(CycleThreadSetupDeathTest, RefusalsWithoutPrivilegeAreReported) {
#if defined(__SANITIZE_ADDRESS__)
  GTEST_SKIP() << "AddressSanitizer makes mlockall a no-op that succeeds";
#elif defined(__has_feature)
#if __has_feature(address_sanitizer)
  GTEST_SKIP() << "AddressSanitizer makes mlockall a no-op that succeeds";
#endif
#endif
  GTEST_FLAG_SET(death_test_style, "threadsafe");
  EXPECT_EXIT(ask_without_privilege(), ::testing::ExitedWithCode(0),
              "SCHED_FIFO 10: refused \\(Operation not permitted\\); memory: not locked "
              "\\(mlockall: .*\\), 256 KiB of stack pre-faulted");
}

}  // namespace
}  // namespace ecat::master
