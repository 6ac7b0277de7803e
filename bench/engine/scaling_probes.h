// SPDX-License-Identifier: Apache-2.0
// What a multi-threaded build's scaling loses besides the builder's own work, measured beside
// it: the per-thread rate of fixed ALU-bound loops when N threads run them at once (the clock
// all cores get, and whether two threads share a core's ports), of a memory stream shaped like
// the build's (each cluster's input bytes read, its object's bytes written), and the process's
// minor page faults (a fault in a parallel region takes the kernel's lock on the address space).
#pragma once

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdint>
#include <cstring>
#include <thread>
#include <vector>

#include <sys/resource.h>

#if defined(__SSE2__)
#include <emmintrin.h>
#endif

namespace clastrace::bench {

// Minor page faults of the whole process so far.
inline uint64_t minor_faults() {
    rusage u{};
    getrusage(RUSAGE_SELF, &u);
    return uint64_t(u.ru_minflt);
}

// Evicts [p, p + n) from every cache of the machine (x86 CLFLUSH; elsewhere nothing): a build
// that runs next reads and writes those bytes in memory, as a build of data not touched since
// the last frame would, instead of in the caches its previous run left them in.
inline void evict_lines(const void* p, size_t n) {
#if defined(__SSE2__)
    const auto* b = static_cast<const char*>(p);
    for (size_t i = 0; i < n; i += 64) _mm_clflush(b + i);
    if (n) _mm_clflush(b + n - 1);
    _mm_mfence();
#else
    (void)p;
    (void)n;
#endif
}

// One dependent chain of multiply-adds: its rate follows the core's clock and nothing else
// (latency-bound, so an SMT sibling running the same loop barely slows it).
inline uint64_t dependent_chain(uint64_t iterations, uint64_t seed) {
    uint64_t x = seed;
    for (uint64_t i = 0; i < iterations; ++i) {
        x = x * 6364136223846793005ull + 1442695040888963407ull;
        asm volatile("" : "+r"(x));  // keeps the chain in a register, unvectorized
    }
    return x;
}

// Eight independent chains: bound by the multiplier's throughput, so a sibling hardware thread
// on the same core halves it while the clock alone moves it as much as the chain.
inline uint64_t independent_chains(uint64_t iterations, uint64_t seed) {
    uint64_t x[8];
    for (int k = 0; k < 8; ++k) x[k] = seed + uint64_t(k);
    for (uint64_t i = 0; i < iterations; ++i)
        for (int k = 0; k < 8; ++k) {
            x[k] = x[k] * 6364136223846793005ull + 1442695040888963407ull;
            asm volatile("" : "+r"(x[k]));
        }
    uint64_t r = 0;
    for (int k = 0; k < 8; ++k) r ^= x[k];
    return r;
}

// Mean over `threads` threads, all started together, of each thread's wall time for `kernel`.
template <class Kernel>
double mean_thread_seconds(int threads, Kernel kernel) {
    std::atomic<int> waiting{threads};
    std::vector<double> seconds(size_t(threads), 0.0);
    std::vector<uint64_t> sinks(size_t(threads), 0);
    std::vector<std::thread> pool;
    for (int t = 0; t < threads; ++t)
        pool.emplace_back([&, t] {
            waiting.fetch_sub(1);
            while (waiting.load() > 0) {}
            const auto t0 = std::chrono::steady_clock::now();
            sinks[size_t(t)] = kernel(uint64_t(t));
            seconds[size_t(t)] =
                std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
        });
    for (std::thread& th : pool) th.join();
    double sum = 0;
    uint64_t sink = 0;
    for (int t = 0; t < threads; ++t) sum += seconds[size_t(t)], sink ^= sinks[size_t(t)];
    asm volatile("" : : "r"(sink));
    return sum / threads;
}

// The build's memory traffic without its work: `pieces` pieces (clusters), each reading
// `in_bytes` from one buffer and writing `out_bytes` to another, both buffers as large as the
// build's inputs and objects and touched beforehand; N threads take 1/N of the pieces each,
// each call another thread's share of the last call (as the build's dynamic scheduling moves a
// cluster from thread to thread between runs, so that its lines come from another core's cache).
class TrafficProbe {
public:
    TrafficProbe(size_t pieces, size_t in_bytes, size_t out_bytes)
        : pieces_(pieces),
          in_bytes_(in_bytes),
          out_bytes_(out_bytes),
          src_(pieces * in_bytes, 1),
          dst_(pieces * out_bytes, 0) {}
    // Mean seconds of a thread's share, times `threads`: equal at every count when the memory
    // system gives each thread what one thread gets alone.
    double seconds(int threads) {
        const uint64_t shift = calls_++;
        return threads * mean_thread_seconds(threads, [&](uint64_t t) {
                   const uint64_t share = (t + shift) % uint64_t(threads);
                   return stream(pieces_ * share / threads, pieces_ * (share + 1) / threads);
               });
    }

private:
    uint64_t stream(size_t first, size_t last) {
        uint64_t sum = 0;
        for (size_t p = first; p < last; ++p) {
            const unsigned char* in = src_.data() + p * in_bytes_;
            for (size_t b = 0; b + 8 <= in_bytes_; b += 8) {
                uint64_t w;
                std::memcpy(&w, in + b, 8);
                sum += w;
            }
            std::memset(dst_.data() + p * out_bytes_, int(sum & 0xFF), out_bytes_);
        }
        return sum;
    }
    size_t pieces_, in_bytes_, out_bytes_;
    uint64_t calls_ = 0;
    std::vector<unsigned char> src_, dst_;
};

// Seconds per thread of the probes at one thread count (lower is faster; the traffic probe's
// normalized by TrafficProbe::seconds); keep the best of repeated runs, and divide the 1-thread
// seconds by them for the per-thread rate relative to one thread.
struct CoreRates {
    double chain = 1e30, ports = 1e30, memory = 1e30;
    void keep_best(const CoreRates& r) {
        chain = std::min(chain, r.chain);
        ports = std::min(ports, r.ports);
        memory = std::min(memory, r.memory);
    }
};

// The chain's iterations, and its cycles per iteration on x86-64 (a 64-bit multiply's latency
// of 3 cycles, then an add's 1): the 1-thread chain time gives the clock the build ran at.
inline constexpr uint64_t kChainIterations = uint64_t(1) << 24;
inline constexpr double kChainCyclesPerIteration = 4.0;

// About 20 ms of each ALU loop per thread at 3 GHz (long enough for the clock to settle at the
// all-core level, short beside a build's repeats), then the traffic probe.
inline CoreRates core_rates(int threads, TrafficProbe& traffic) {
    constexpr uint64_t kPortIterations = uint64_t(1) << 23;
    CoreRates r;
    r.chain = mean_thread_seconds(threads,
                                  [](uint64_t t) { return dependent_chain(kChainIterations, t); });
    r.ports = mean_thread_seconds(threads, [](uint64_t t) {
        return independent_chains(kPortIterations, t);
    });
    r.memory = traffic.seconds(threads);
    return r;
}

}  // namespace clastrace::bench
