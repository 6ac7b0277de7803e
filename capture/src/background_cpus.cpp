// SPDX-License-Identifier: Apache-2.0
#include "clastrace/capture/background_cpus.h"

#include "decimal_text.h"

#include <sched.h>

#include <algorithm>
#include <fstream>

namespace clastrace::capture {
namespace {

constexpr unsigned kMaxCpu = 4096;  // the kernel's largest NR_CPUS default

std::optional<unsigned> parse_cpu(const std::string& text) {
    const std::optional<uint64_t> value = parse_decimal(text, 4);
    if (!value || *value >= kMaxCpu) return std::nullopt;
    return unsigned(*value);
}

}  // namespace

std::optional<std::vector<unsigned>> parse_cpu_list(const std::string& text) {
    std::vector<unsigned> cpus;
    size_t at = 0;
    while (at <= text.size()) {
        const size_t comma = std::min(text.find(',', at), text.size());
        const std::string item = text.substr(at, comma - at);
        const size_t dash = item.find('-');
        const auto first = parse_cpu(item.substr(0, dash));
        const auto last = dash == std::string::npos ? first : parse_cpu(item.substr(dash + 1));
        if (!first || !last || *last < *first) return std::nullopt;
        for (unsigned c = *first; c <= *last; ++c) cpus.push_back(c);
        at = comma + 1;
    }
    std::sort(cpus.begin(), cpus.end());
    cpus.erase(std::unique(cpus.begin(), cpus.end()), cpus.end());
    return cpus;
}

std::string format_cpu_list(const std::vector<unsigned>& cpus) {
    if (cpus.empty()) return "none";
    std::string text;
    for (size_t i = 0; i < cpus.size();) {
        size_t j = i;
        while (j + 1 < cpus.size() && cpus[j + 1] == cpus[j] + 1) ++j;
        if (!text.empty()) text += ',';
        text += std::to_string(cpus[i]);
        if (j > i) text += '-' + std::to_string(cpus[j]);
        i = j + 1;
    }
    return text;
}

std::vector<unsigned> background_cpus_for(const BackgroundCpus& setting,
                                          const std::vector<unsigned>& online,
                                          const std::vector<unsigned>& allowed,
                                          const std::vector<unsigned>& reserved,
                                          const std::vector<unsigned>& siblings) {
    switch (setting.mode) {
    case BackgroundCpus::Mode::kApp: return {};
    case BackgroundCpus::Mode::kList: return setting.list;
    case BackgroundCpus::Mode::kSpare: break;
    }
    if (allowed.empty()) return {};  // the application's CPUs unknown: nothing to keep clear of
    auto in = [](const std::vector<unsigned>& list, unsigned cpu) {
        return std::find(list.begin(), list.end(), cpu) != list.end();
    };
    std::vector<unsigned> spare, apart_from_siblings;
    for (unsigned cpu : online)
        if (!in(allowed, cpu) && !in(reserved, cpu)) {
            spare.push_back(cpu);
            if (!in(siblings, cpu)) apart_from_siblings.push_back(cpu);
        }
    // A sibling shares its core's execution units and first caches with an engine thread while
    // both run (SCHED_IDLE yields only the logical CPU): other cores first, siblings when the
    // application holds every core.
    return apart_from_siblings.empty() ? spare : apart_from_siblings;
}

namespace {
std::vector<unsigned> cpu_list_file(const char* path) {  // empty when missing, empty or unreadable
    std::ifstream file(path);
    std::string line;
    if (!std::getline(file, line)) return {};
    return parse_cpu_list(line).value_or(std::vector<unsigned>{});
}
}  // namespace

std::vector<unsigned> online_cpus() { return cpu_list_file("/sys/devices/system/cpu/online"); }

std::vector<unsigned> reserved_cpus() {
    std::vector<unsigned> reserved = cpu_list_file("/sys/devices/system/cpu/isolated");
    for (unsigned c : cpu_list_file("/sys/devices/system/cpu/nohz_full")) reserved.push_back(c);
    return reserved;
}

std::vector<unsigned> smt_siblings(const std::vector<unsigned>& cpus) {
    std::vector<unsigned> siblings;
    for (unsigned cpu : cpus) {
        const std::string path =
            "/sys/devices/system/cpu/cpu" + std::to_string(cpu) + "/topology/thread_siblings_list";
        for (unsigned s : cpu_list_file(path.c_str()))
            if (!std::binary_search(cpus.begin(), cpus.end(), s)) siblings.push_back(s);
    }
    std::sort(siblings.begin(), siblings.end());
    siblings.erase(std::unique(siblings.begin(), siblings.end()), siblings.end());
    return siblings;
}

std::vector<unsigned> thread_cpus(pthread_t thread) {
    cpu_set_t* set = CPU_ALLOC(kMaxCpu);
    if (!set) return {};
    const size_t bytes = CPU_ALLOC_SIZE(kMaxCpu);
    std::vector<unsigned> cpus;
    if (pthread_getaffinity_np(thread, bytes, set) == 0)
        for (unsigned c = 0; c < kMaxCpu; ++c)
            if (CPU_ISSET_S(c, bytes, set)) cpus.push_back(c);
    CPU_FREE(set);
    return cpus;
}

std::vector<unsigned> calling_thread_cpus() { return thread_cpus(pthread_self()); }

bool place_thread(pthread_t thread, const std::vector<unsigned>& cpus) {
    if (cpus.empty()) return false;
    cpu_set_t* set = CPU_ALLOC(kMaxCpu);
    if (!set) return false;
    const size_t bytes = CPU_ALLOC_SIZE(kMaxCpu);
    CPU_ZERO_S(bytes, set);
    for (unsigned c : cpus)
        if (c < kMaxCpu) CPU_SET_S(c, bytes, set);
    const bool placed = pthread_setaffinity_np(thread, bytes, set) == 0;
    CPU_FREE(set);
    return placed;
}

bool place_calling_thread(const std::vector<unsigned>& cpus) {
    return place_thread(pthread_self(), cpus);
}

}  // namespace clastrace::capture
