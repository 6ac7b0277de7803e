// SPDX-License-Identifier: Apache-2.0
#include "failing_source.h"

#include <cstring>
#include <filesystem>

namespace clastrace::traces::testing {

namespace {

thread_local std::string last_read_error;

// False once `f` has failed as many reads as it may.
bool count_failure(ReadFailure& f) {
    uint32_t n = f.failed.load();
    do {
        if (n >= f.max_failures) return false;
    } while (!f.failed.compare_exchange_weak(n, n + 1));
    return true;
}

class FailingSource final : public ByteSource {
public:
    FailingSource(const std::vector<uint8_t>& bytes, std::shared_ptr<ReadFailure> failure)
        : bytes_(bytes), failure_(std::move(failure)), opener_(std::this_thread::get_id()) {
        size_ = bytes.size();
    }
    bool read_at(uint64_t offset, size_t n, uint8_t* dst) override {
        if (offset > size_ || n > size_ - offset) {
            last_read_error = "unexpected end of file";
            return false;
        }
        const bool here =
            !failure_->read_ahead_thread_only || std::this_thread::get_id() != opener_;
        if (here && offset < failure_->to && offset + n > failure_->from &&
            count_failure(*failure_)) {
            last_read_error = kInjectedReadError;
            return false;
        }
        if (n) std::memcpy(dst, bytes_.data() + offset, n);
        return true;
    }
    std::string last_error() const override { return last_read_error; }

private:
    const std::vector<uint8_t>& bytes_;
    std::shared_ptr<ReadFailure> failure_;
    std::thread::id opener_;
};

}  // namespace

std::unique_ptr<TraceReader> open_failing(const std::vector<uint8_t>& bytes,
                                          const std::string& name,
                                          std::shared_ptr<ReadFailure> failure, TraceError* error) {
    return TraceReader::open_source(std::make_unique<FailingSource>(bytes, std::move(failure)),
                                    name, error);
}

size_t thread_count() {
    size_t n = 0;
    for ([[maybe_unused]] const auto& task : std::filesystem::directory_iterator("/proc/self/task"))
        ++n;
    return n;
}

}  // namespace clastrace::traces::testing
