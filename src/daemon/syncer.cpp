#include "syncer.hpp"

#include <pthread.h>

#include <cerrno>
#include <csignal>

namespace turncal::daemon {

Syncer::Syncer(int (*fsync)(int fd)) : fsync_(fsync) {
  // The thread takes no signal: the daemon hears SIGTERM on its loop's
  // signalfd, which works only while every thread blocks it (a thread
  // started unblocked, before the loop's set-up, would take SIGTERM's
  // default action: the process killed mid-run). Started with all blocked.
  sigset_t all, old;
  sigfillset(&all);
  pthread_sigmask(SIG_SETMASK, &all, &old);
  try {
    thread_ = std::thread([this] { run(); });
  } catch (...) {
    pthread_sigmask(SIG_SETMASK, &old, nullptr);
    throw;
  }
  pthread_sigmask(SIG_SETMASK, &old, nullptr);
}

Syncer::~Syncer() {
  {
    const std::lock_guard<std::mutex> l(m_);
    stop_ = true;
  }
  wake_.notify_one();
  thread_.join();
}

void Syncer::request(int fd, std::uint64_t mark) {
  {
    const std::lock_guard<std::mutex> l(m_);
    want_fd_ = fd;
    want_mark_ = mark;
  }
  wake_.notify_one();
}

int Syncer::take_error() {
  const std::lock_guard<std::mutex> l(m_);
  const int e = error_;
  error_ = 0;
  return e;
}

void Syncer::wait_idle() {
  std::unique_lock<std::mutex> l(m_);
  idle_.wait(l, [&] { return want_fd_ < 0 && !busy_; });
}

std::uint64_t Syncer::synced() const {
  const std::lock_guard<std::mutex> l(m_);
  return synced_;
}

void Syncer::new_file() {
  const std::lock_guard<std::mutex> l(m_);
  synced_ = 0;
  failed_ = false;
}

unsigned long Syncer::done() const {
  const std::lock_guard<std::mutex> l(m_);
  return done_;
}

void Syncer::run() {
  std::unique_lock<std::mutex> l(m_);
  for (;;) {
    wake_.wait(l, [&] { return stop_ || want_fd_ >= 0; });
    if (want_fd_ < 0) return;  // stopped, nothing left to do
    const int fd = want_fd_;
    const std::uint64_t mark = want_mark_;
    want_fd_ = -1;
    busy_ = true;
    l.unlock();
    int err = 0;
    while (fsync_(fd) != 0) {
      if (errno == EINTR) continue;
      err = errno;
      break;
    }
    l.lock();
    busy_ = false;
    ++done_;
    if (err != 0 && error_ == 0) error_ = err;
    // after a failed fsync a later one may succeed with the lost pages
    // gone (the kernel reports a writeback error once): nothing after the
    // failure is known to be on disk
    if (err != 0) failed_ = true;
    if (err == 0 && !failed_) synced_ = mark;
    if (want_fd_ < 0) idle_.notify_all();
  }
}

}  // namespace turncal::daemon
