// SPDX-License-Identifier: Apache-2.0
// The bytes of one captured range: a copy of its own, or a view into memory that stays
// unchanged for as long as a shared keeper lives. A served build's ranges lie in the engine's
// image already (its inputs as the pause copied them in, its outputs as the build wrote them);
// viewing them there instead of copying them saves a pass over every captured byte and an
// allocation per range, and the image goes back to the region pool once the last view is
// gone. (Inputs the build writes over are turned back into copies: ServedMemory::keepInputsAsRead.)
#pragma once

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <initializer_list>
#include <memory>
#include <span>
#include <vector>

namespace clastrace::capture {

class CapturedBytes {
public:
    CapturedBytes() = default;
    CapturedBytes(std::vector<uint8_t> copy) : copy_(std::move(copy)) {}  // NOLINT: a copy converts
    CapturedBytes(std::initializer_list<uint8_t> copy) : copy_(copy) {}
    // `size` bytes at `data`, which `keeper` keeps alive and unchanged.
    static CapturedBytes view(std::shared_ptr<const void> keeper, const uint8_t* data,
                              size_t size) {
        CapturedBytes b;
        b.keeper_ = std::move(keeper);
        b.view_ = data;
        b.view_size_ = size;
        return b;
    }

    // A view owned by nobody, of bytes that outlive every use of it.
    static CapturedBytes borrow(const uint8_t* data, size_t size) {
        return view(std::shared_ptr<const void>(std::shared_ptr<const void>(), data), data, size);
    }

    const uint8_t* data() const { return keeper_ ? view_ : copy_.data(); }
    size_t size() const { return keeper_ ? view_size_ : copy_.size(); }
    bool empty() const { return size() == 0; }
    const uint8_t* begin() const { return data(); }
    const uint8_t* end() const { return data() + size(); }
    uint8_t operator[](size_t i) const { return data()[i]; }
    std::span<const uint8_t> span() const { return {data(), size()}; }
    bool is_view() const { return keeper_ != nullptr; }
    bool views(const void* kept) const {
        return keeper_ && keeper_.get() == kept;
    }  // kept by that object
    // Bytes this range holds of its own (a view holds none: its keeper is counted elsewhere).
    size_t owned_size() const { return keeper_ ? 0 : copy_.size(); }

    // A copy of [first, last), dropping any view.
    template <class Iterator>
    void assign(Iterator first, Iterator last) {
        keeper_.reset();
        copy_.assign(first, last);
    }
    // `size` bytes of its own for a reader to fill, dropping any view.
    uint8_t* fill(size_t size) {
        keeper_.reset();
        copy_.resize(size);
        return copy_.data();
    }

    friend bool operator==(const CapturedBytes& a, const std::vector<uint8_t>& b) {
        return a.size() == b.size() && std::equal(a.begin(), a.end(), b.begin());
    }

private:
    std::vector<uint8_t> copy_;
    std::shared_ptr<const void> keeper_;
    const uint8_t* view_ = nullptr;
    size_t view_size_ = 0;
};

}  // namespace clastrace::capture
