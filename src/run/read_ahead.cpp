#include "turncal/run/read_ahead.hpp"

#include <exception>
#include <utility>

namespace turncal::run {
namespace {
constexpr std::size_t kBatch = 4096;  ///< records a batch holds
constexpr std::size_t kAhead = 4;     ///< batches parsed ahead at most
}  // namespace

ReadAheadLogReader::ReadAheadLogReader(can::LogReader reader)
    : reader_(std::move(reader)), thread_([this] { produce(); }) {}

ReadAheadLogReader::~ReadAheadLogReader() {
  {
    const std::lock_guard lock(m_);
    stop_ = true;
  }
  cv_.notify_all();
  thread_.join();
}

void ReadAheadLogReader::produce() {
  // an exception (out of memory) ends the reading, and next() throws it
  // where the plain reader would have: never taken for a damaged log
  try {
    for (;;) {
      Batch b;
      {
        std::unique_lock lock(m_);
        cv_.wait(lock, [&] { return stop_ || full_.size() < kAhead; });
        if (stop_) return;
        if (!free_.empty()) {
          b = std::move(free_.back());
          free_.pop_back();
        }
      }
      b.records.resize(kBatch);
      b.lines.clear();
      b.error.reset();
      std::size_t n = 0;
      while (n < kBatch) {
        auto got = reader_.next(b.records[n]);
        if (!got) {
          b.error = std::move(got).error();
          break;
        }
        if (!*got) break;
        b.lines.push_back(reader_.line_number());
        ++n;
      }
      b.end = n < kBatch;
      b.records.resize(n);
      b.last_line = reader_.line_number();
      const bool end = b.end;
      {
        const std::lock_guard lock(m_);
        full_.push_back(std::move(b));
      }
      cv_.notify_all();
      if (end) return;
    }
  } catch (...) {
    {
      const std::lock_guard lock(m_);
      thrown_ = std::current_exception();
    }
    cv_.notify_all();
  }
}

Result<const can::LogRecord*> ReadAheadLogReader::next() {
  while (!have_cur_ || at_ == cur_.records.size()) {
    if (have_cur_) {
      line_ = cur_.last_line;
      if (cur_.error) return *cur_.error;
      if (cur_.end) return nullptr;
    }
    std::unique_lock lock(m_);
    if (have_cur_) free_.push_back(std::move(cur_));
    cv_.notify_all();
    cv_.wait(lock, [&] { return !full_.empty() || thrown_ != nullptr; });
    if (full_.empty()) std::rethrow_exception(thrown_);
    cur_ = std::move(full_.front());
    full_.pop_front();
    have_cur_ = true;
    at_ = 0;
  }
  line_ = cur_.lines[at_];
  return &cur_.records[at_++];
}

}  // namespace turncal::run
