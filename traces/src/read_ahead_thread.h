// SPDX-License-Identifier: Apache-2.0
// The trace reader's read-ahead thread: one job at a time, its result or its exception handed to
// the reader's thread.
#pragma once

#include <clastrace/common/debug_assert.h>

#include <condition_variable>
#include <exception>
#include <functional>
#include <mutex>
#include <optional>
#include <system_error>
#include <thread>
#include <utility>

namespace clastrace::traces::reader {

// One job at a time on a thread kept for the reader's life. A thread per chunk read ahead
// (std::async) paid its start, its end and the release of its stack's pages every 4 MiB.
template <class Result>
class ReadAheadThread {
public:
    ReadAheadThread() = default;
    ReadAheadThread(const ReadAheadThread&) = delete;
    ReadAheadThread& operator=(const ReadAheadThread&) = delete;
    ~ReadAheadThread() {
        {
            std::lock_guard lock(mutex_);
            stop_ = true;
        }
        changed_.notify_all();
        if (thread_.joinable()) thread_.join();
    }

    // Runs `job` on the thread; false when no thread can be started (a process at its thread
    // limit), and the reader's thread then does the work itself. The job given before must have
    // been taken or dropped.
    bool run(std::function<Result()> job) {
        CLASTRACE_DEBUG_ASSERT(!given_);
        if (!thread_.joinable()) {
            try {
                thread_ = std::thread([this] { serve(); });
            } catch (const std::system_error&) {
                return false;
            }
        }
        {
            std::lock_guard lock(mutex_);
            job_ = std::move(job);
        }
        given_ = true;
        changed_.notify_all();
        return true;
    }
    // True from run() until get() or drop() (only the reader's thread calls these).
    bool valid() const { return given_; }
    void wait() {
        std::unique_lock lock(mutex_);
        changed_.wait(lock, [&] { return done_; });
    }
    Result get() {
        wait();
        given_ = false;
        std::lock_guard lock(mutex_);
        done_ = false;
        if (failure_) std::rethrow_exception(std::exchange(failure_, nullptr));
        Result r = std::move(*result_);
        result_.reset();
        return r;
    }
    void drop() {
        if (!given_) return;
        wait();
        given_ = false;
        std::lock_guard lock(mutex_);
        done_ = false;
        result_.reset();
        failure_ = nullptr;
    }

private:
    void serve() {
        std::unique_lock lock(mutex_);
        for (;;) {
            changed_.wait(lock, [&] { return stop_ || job_ != nullptr; });
            if (stop_) return;
            std::function<Result()> job = std::exchange(job_, nullptr);
            lock.unlock();
            std::optional<Result> r;
            std::exception_ptr failure;
            try {
                r.emplace(job());
            } catch (...) {
                failure = std::current_exception();
            }
            lock.lock();
            result_ = std::move(r);
            failure_ = failure;
            done_ = true;
            changed_.notify_all();
        }
    }
    std::mutex mutex_;
    std::condition_variable changed_;
    std::function<Result()> job_;  // under mutex_, like the four below
    std::optional<Result> result_;
    std::exception_ptr failure_;
    bool done_ = false;
    bool stop_ = false;
    bool given_ = false;  // the reader's thread's own
    std::thread thread_;
};

}  // namespace clastrace::traces::reader
