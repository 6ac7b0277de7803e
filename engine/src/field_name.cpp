// SPDX-License-Identifier: Apache-2.0
#include "clastrace/engine/field_name.h"

#include <algorithm>
#include <charconv>
#include <cstring>
#include <ostream>

namespace clastrace::engine {

FieldName& FieldName::operator=(const FieldName& other) {
    if (this != &other) {
        size_ = 0;
        append(other.view());
    }
    return *this;
}

FieldName& FieldName::operator=(FieldName&& other) noexcept {
    if (this != &other) {
        delete[] heap_;
        take(other);
    }
    return *this;
}

void FieldName::take(FieldName& other) noexcept {
    heap_ = other.heap_;
    size_ = other.size_;
    capacity_ = other.capacity_;
    if (!heap_) std::memcpy(inline_, other.inline_, size_ + 1);
    other.heap_ = nullptr;
    other.size_ = 0;
    other.capacity_ = kInline;
    other.inline_[0] = '\0';
}

FieldName& FieldName::append(std::string_view text) {
    const size_t size = size_ + text.size();
    if (size > capacity_) {
        const size_t capacity = std::max(size, 2 * size_t(capacity_));
        char* grown = new char[capacity + 1];
        std::memcpy(grown, data(), size_);
        delete[] heap_;
        heap_ = grown;
        capacity_ = uint32_t(capacity);
    }
    char* d = data();
    if (!text.empty()) std::memcpy(d + size_, text.data(), text.size());
    size_ = uint32_t(size);
    d[size_] = '\0';
    return *this;
}

FieldName& FieldName::append_number(uint64_t value) {
    char digits[20];
    const char* end = std::to_chars(digits, digits + sizeof digits, value).ptr;
    return append({digits, size_t(end - digits)});
}

std::ostream& operator<<(std::ostream& out, const FieldName& name) { return out << name.view(); }

}  // namespace clastrace::engine
