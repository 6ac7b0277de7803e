// SPDX-License-Identifier: Apache-2.0
// The name of the field a recorded access went through ("srcInfosArray[3].vertexBuffer"),
// kept inside the access: every op names several accesses, and a heap string each was the
// largest count of a replay's allocations (docs/benchmarks.md, "Replay's own work per op").
// Names longer than kInline characters (a KHR build's long geometry paths) go to the heap.
#pragma once

#include <cstddef>
#include <cstdint>
#include <iosfwd>
#include <string>
#include <string_view>

namespace clastrace::engine {

class FieldName {
public:
    static constexpr size_t kInline = 47;  // the object is 64 bytes

    FieldName() = default;
    // Implicit, as the std::string it replaces was: accesses are named with literals.
    FieldName(std::string_view text) { append(text); }  // NOLINT(google-explicit-constructor)
    FieldName(const char* text) : FieldName(std::string_view(text)) {}         // NOLINT
    FieldName(const std::string& text) : FieldName(std::string_view(text)) {}  // NOLINT
    FieldName(const FieldName& other) : FieldName(other.view()) {}
    FieldName(FieldName&& other) noexcept { take(other); }
    FieldName& operator=(const FieldName& other);
    FieldName& operator=(FieldName&& other) noexcept;
    ~FieldName() { delete[] heap_; }

    FieldName& append(std::string_view text);
    FieldName& append_number(uint64_t value);  // in decimal

    std::string_view view() const { return {data(), size_}; }
    operator std::string_view() const { return view(); }  // NOLINT: read where text was
    const char* c_str() const { return data(); }
    std::string str() const { return std::string(view()); }
    size_t size() const { return size_; }
    bool empty() const { return size_ == 0; }
    bool starts_with(std::string_view prefix) const { return view().starts_with(prefix); }
    bool ends_with(std::string_view suffix) const { return view().ends_with(suffix); }
    size_t find(std::string_view text, size_t from = 0) const { return view().find(text, from); }

    // One overload per argument type, so a literal or a std::string picks its own exactly.
    friend bool operator==(const FieldName& a, const FieldName& b) { return a.view() == b.view(); }
    friend bool operator==(const FieldName& a, std::string_view b) { return a.view() == b; }
    friend bool operator==(const FieldName& a, const char* b) { return a.view() == b; }
    friend bool operator==(const FieldName& a, const std::string& b) { return a.view() == b; }
    // Messages name fields: "srcInfosArray[3] = 0x..." is a std::string, as before.
    friend std::string operator+(const FieldName& a, std::string_view b) {
        return std::string(a.view()).append(b);
    }
    friend std::string operator+(std::string_view a, const FieldName& b) {
        return std::string(a).append(b.view());
    }

private:
    char* data() { return heap_ ? heap_ : inline_; }
    const char* data() const { return heap_ ? heap_ : inline_; }
    void take(FieldName& other) noexcept;

    char* heap_ = nullptr;  // when the name outgrew inline_
    uint32_t size_ = 0;
    uint32_t capacity_ = kInline;  // characters, less the terminating zero
    char inline_[kInline + 1] = {};
};

std::ostream& operator<<(std::ostream& out, const FieldName& name);

}  // namespace clastrace::engine
