// The daemon's syncer: an fsync asked for returns at once however long the
// disk takes, a failure comes back to the loop, and wait_idle holds the
// closing of a file until its fsync is done.
#include <doctest/doctest.h>

#include <pthread.h>

#include <atomic>
#include <cerrno>
#include <chrono>
#include <csignal>
#include <thread>

#include "syncer.hpp"

using turncal::daemon::Syncer;
using namespace std::chrono_literals;

namespace {

std::atomic<bool> g_release{false};  // the slow disk lets the fsync finish
std::atomic<int> g_calls{0};
std::atomic<int> g_last_fd{-1};

int slow_fsync(int fd) {
  ++g_calls;
  g_last_fd = fd;
  while (!g_release) std::this_thread::sleep_for(1ms);
  if (fd == 99) {
    errno = EIO;
    return -1;
  }
  return 0;
}

std::atomic<int> g_sigterm_blocked{-1};

int mask_fsync(int) {
  sigset_t cur;
  pthread_sigmask(SIG_BLOCK, nullptr, &cur);
  g_sigterm_blocked = sigismember(&cur, SIGTERM);
  return 0;
}

}  // namespace

TEST_SUITE("syncer") {
  TEST_CASE("its thread blocks SIGTERM, which the daemon takes on its signalfd") {
    // made where SIGTERM is not blocked (the daemon's first moments)
    sigset_t none, old;
    sigemptyset(&none);
    pthread_sigmask(SIG_SETMASK, &none, &old);
    {
      Syncer s(mask_fsync);
      s.request(3);
      s.wait_idle();
    }
    pthread_sigmask(SIG_SETMASK, &old, nullptr);
    CHECK(g_sigterm_blocked == 1);
  }

  TEST_CASE("an fsync that waits on the disk does not hold the caller; its failure comes back") {
    g_release = false;
    g_calls = 0;
    Syncer s(slow_fsync);
    s.request(7, 100);
    // the caller goes on while the fsync waits (it returned to get here)
    for (int i = 0; i < 2000 && g_calls == 0; ++i) std::this_thread::sleep_for(1ms);
    REQUIRE(g_calls == 1);
    CHECK(s.done() == 0);
    CHECK(s.take_error() == 0);
    CHECK(s.synced() == 0);  // nothing is surely on disk yet
    // asked twice more while it runs: one more fsync, of the last asked
    s.request(8, 150);
    s.request(99, 200);
    g_release = true;
    s.wait_idle();
    CHECK(s.done() == 2);
    CHECK(g_calls == 2);
    CHECK(g_last_fd == 99);
    CHECK(s.take_error() == EIO);
    CHECK(s.take_error() == 0);  // told once
    CHECK(s.synced() == 100);    // the first fsync's mark; the failed one's is not
  }

  TEST_CASE("wait_idle returns only when the fsync under way is done") {
    g_release = false;
    g_calls = 0;
    Syncer s(slow_fsync);
    s.request(5);
    std::atomic<bool> idle{false};
    std::thread waiter([&] {
      s.wait_idle();
      idle = true;
    });
    std::this_thread::sleep_for(50ms);
    CHECK_FALSE(idle);  // the fsync still waits on the disk
    g_release = true;
    waiter.join();
    CHECK(idle);
    CHECK(s.done() == 1);
  }
}
