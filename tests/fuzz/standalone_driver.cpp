// SPDX-License-Identifier: Apache-2.0
// Runs one fuzz target (its LLVMFuzzerTestOneInput) without libFuzzer, so the normal gcc
// build fuzzes too and ctest can run every target for a fixed time. It runs each seed once,
// then seeded mutations of them until the time is up. Blind (no coverage feedback), so it
// mutates the way .clt files break: bit flips, byte sets, truncation, byte and chunk
// splicing, huge values in length fields, ill-formed UTF-8, edits inside decompressed chunk
// payloads, with the checksums resealed half of the time so the edit gets past them.
//
// An input that crashes, aborts, runs longer than --input-seconds or drives the process
// past --rss-limit-mb is written to the findings folder and the run exits 1.
//
//   fuzz_TARGET [--seconds N] [--input-seconds N] [--rss-limit-mb N] [--seed N]
//               [--findings DIR] [--skip TEXT]... SEED_FILE_OR_DIR...
// --seconds 0 (the default) runs each input once: how a finding is reproduced.
#include "file_format.h"

#include <zstd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <csignal>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <string>
#include <thread>
#include <vector>

#include <fcntl.h>
#include <unistd.h>

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size);

namespace {

namespace f = clastrace::traces::format;
using Bytes = std::vector<uint8_t>;
using Clock = std::chrono::steady_clock;

struct Seed {
    std::string name;
    Bytes bytes;
};

struct Settings {
    double seconds = 0;
    double input_seconds = 10;
    uint64_t rss_limit_mb = 2048;
    uint64_t seed = 1;
    std::string findings = "fuzz-findings";
    std::vector<std::string> skip;
    std::vector<std::string> inputs;
};

constexpr size_t kMaxInputBytes = 4u << 20;

// What the crash handler and the watchdog need, set before each input runs.
const Bytes* g_input = nullptr;
char g_history[512];    // where the running input came from
char g_findings[4096];  // folder of findings
char g_target[128];
std::atomic<int64_t> g_started_ns{0};  // 0 between inputs

// Async-signal-safe: only write(2), open(2) and fixed buffers.
void say(const char* text) { (void)!::write(2, text, std::strlen(text)); }

void save_finding(const char* kind, const char* why) {
    uint64_t h = 1469598103934665603ull;  // FNV-1a names the file by its bytes
    const Bytes& in = *g_input;
    for (uint8_t b : in) h = (h ^ b) * 1099511628211ull;
    char name[4300];
    static const char digits[] = "0123456789abcdef";
    char hex[17];
    for (int i = 15; i >= 0; --i, h >>= 4) hex[i] = digits[h & 15];
    hex[16] = 0;
    std::snprintf(name, sizeof name, "%s/%s-%s-%s", g_findings, g_target, kind, hex);
    int fd = ::open(name, O_WRONLY | O_CREAT | O_TRUNC, 0644);
    if (fd >= 0) {
        (void)!::write(fd, in.data(), in.size());
        ::close(fd);
    }
    say("\n");
    say(g_target);
    say(": ");
    say(why);
    say("\n  input: ");
    say(g_history);
    say("\n  written to ");
    say(name);
    say("\n  reproduce: ");
    say(g_target);
    say(" ");
    say(name);
    say("\n");
}

void on_fatal_signal(int sig) {
    char why[64];
    std::snprintf(why, sizeof why, "the input crashed (signal %d, %s)", sig, sigabbrev_np(sig));
    if (g_input) save_finding("crash", why);
    ::_exit(1);
}

void install_crash_handlers() {
    static std::vector<char> alt(1 << 16);  // a stack overflow still reaches the handler
    stack_t ss{};
    ss.ss_sp = alt.data();
    ss.ss_size = alt.size();
    sigaltstack(&ss, nullptr);
    struct sigaction sa {};
    sa.sa_handler = on_fatal_signal;
    sa.sa_flags = SA_ONSTACK | SA_RESETHAND;
    for (int sig : {SIGSEGV, SIGBUS, SIGILL, SIGFPE, SIGABRT}) sigaction(sig, &sa, nullptr);
}

uint64_t resident_mb() {
    std::ifstream statm("/proc/self/statm");
    uint64_t pages = 0, resident = 0;
    statm >> pages >> resident;
    return resident * uint64_t(sysconf(_SC_PAGESIZE)) >> 20;
}

// Stops the run when the current input takes too long or too much memory.
void watch(const Settings& s) {
    for (;;) {
        std::this_thread::sleep_for(std::chrono::milliseconds(50));
        const int64_t started = g_started_ns.load();
        if (started == 0) continue;
        const double ran = double(Clock::now().time_since_epoch().count() - started) * 1e-9;
        if (ran > s.input_seconds) {
            char why[128];
            std::snprintf(why, sizeof why, "the input ran longer than %.0f s (--input-seconds)",
                          s.input_seconds);
            save_finding("slow", why);
            ::_exit(1);
        }
        if (const uint64_t mb = resident_mb(); mb > s.rss_limit_mb) {
            char why[128];
            std::snprintf(why, sizeof why,
                          "the input took %llu MiB of memory (--rss-limit-mb %llu)",
                          (unsigned long long)mb, (unsigned long long)s.rss_limit_mb);
            save_finding("memory", why);
            ::_exit(1);
        }
    }
}

class Random {
public:
    explicit Random(uint64_t seed) : state_(seed) {}
    uint64_t next() {  // splitmix64
        uint64_t z = (state_ += 0x9e3779b97f4a7c15ull);
        z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ull;
        z = (z ^ (z >> 27)) * 0x94d049bb133111ebull;
        return z ^ (z >> 31);
    }
    size_t below(size_t n) { return n ? size_t(next() % n) : 0; }
    bool chance(unsigned percent) { return below(100) < percent; }

private:
    uint64_t state_;
};

// Offsets of chunk headers, found by their magic so a damaged file still has some.
std::vector<size_t> chunk_starts(const Bytes& b) {
    std::vector<size_t> out;
    uint8_t magic[4];
    std::memcpy(magic, &f::kChunkMagic, 4);
    for (size_t at = 0; at + f::kChunkHeaderSize <= b.size(); ++at)
        if (std::memcmp(b.data() + at, magic, 4) == 0) out.push_back(at);
    return out;
}

// Bytes of the chunk at `at`: its header's length when that fits, else up to the next magic.
size_t chunk_span(const Bytes& b, size_t at, const std::vector<size_t>& starts) {
    const uint64_t claimed = f::kChunkHeaderSize + uint64_t(f::load<uint32_t>(b.data() + at + 20));
    if (at + claimed <= b.size()) return size_t(claimed);
    auto next = std::upper_bound(starts.begin(), starts.end(), at);
    return (next == starts.end() ? b.size() : *next) - at;
}

// Makes every checksum right again, so edits reach what lies behind the checksums.
void reseal(Bytes& b) {
    if (b.size() >= f::kFileHeaderSize && std::memcmp(b.data(), f::kFileMagic, 8) == 0) {
        f::FileHeader h = f::load<f::FileHeader>(b.data());
        if (f::kFileHeaderSize + uint64_t(h.trace_header_size) <= b.size()) {
            h.checksum =
                f::file_header_checksum(h, b.data() + f::kFileHeaderSize, h.trace_header_size);
            std::memcpy(b.data(), &h, sizeof h);
        }
    }
    const std::vector<size_t> starts = chunk_starts(b);
    for (size_t at : starts) {
        f::ChunkHeader h = f::load<f::ChunkHeader>(b.data() + at);
        if (at + f::kChunkHeaderSize + uint64_t(h.compressed_size) <= b.size())
            h.payload_checksum =
                f::checksum(b.data() + at + f::kChunkHeaderSize, h.compressed_size);
        h.header_checksum = f::chunk_header_checksum(h);
        std::memcpy(b.data() + at, &h, sizeof h);
    }
}

const std::vector<std::string> kIllFormedUtf8 = {
    "\xe9",     "\xff",        "\x80", "\xc3\x28", "\xc0\xaf", "\xed\xa0\x80", "\xf4\x90\x80\x80",
    "\xe2\x82", "\xfe\xfe\xff"};

class Mutator {
public:
    Mutator(const std::vector<Seed>& corpus, uint64_t seed) : corpus_(corpus), rng_(seed) {}

    // Replaces `b` with a mutation of a seed; `history` says which seed and what was done.
    void next(Bytes& b, std::string& history) {
        const Seed& seed = corpus_[rng_.below(corpus_.size())];
        b = seed.bytes;
        history = seed.name + ":";
        for (size_t n = 1 + rng_.below(4); n > 0; --n) history += " " + mutate(b);
        if (rng_.chance(50)) {
            reseal(b);
            history += " reseal";
        }
        if (b.size() > kMaxInputBytes) b.resize(kMaxInputBytes);
    }

private:
    std::string mutate(Bytes& b) {
        switch (rng_.below(10)) {
        case 0: return flip_bit(b);
        case 1: return set_byte(b);
        case 2: return truncate(b);
        case 3: return splice_bytes(b);
        case 4: return splice_chunk(b);
        case 5: return huge_length(b);
        case 6: return ill_formed_utf8(b);
        default: return edit_payload(b);  // most of a trace lies behind compression
        }
    }

    std::string flip_bit(Bytes& b) {
        if (b.empty()) return "flip(empty)";
        const size_t at = rng_.below(b.size());
        b[at] ^= uint8_t(1u << rng_.below(8));
        return "flip@" + std::to_string(at);
    }
    std::string set_byte(Bytes& b) {
        if (b.empty()) return "set(empty)";
        static const uint8_t values[] = {0, 1, 0x7f, 0x80, 0xfe, 0xff};
        const size_t at = rng_.below(b.size());
        b[at] = rng_.chance(50) ? values[rng_.below(sizeof values)] : uint8_t(rng_.next());
        return "set@" + std::to_string(at);
    }
    std::string truncate(Bytes& b) {
        b.resize(rng_.below(b.size() + 1));
        return "cut@" + std::to_string(b.size());
    }
    std::string splice_bytes(Bytes& b) {
        const Bytes& other = corpus_[rng_.below(corpus_.size())].bytes;
        if (other.empty()) return "splice(empty)";
        const size_t from = rng_.below(other.size()),
                     n = 1 + rng_.below(std::min<size_t>(other.size() - from, 4096));
        const size_t at = rng_.below(b.size() + 1);
        if (rng_.chance(50)) {
            b.insert(b.begin() + at, other.begin() + from, other.begin() + from + n);
        } else {
            b.resize(std::max(b.size(), at + n));
            std::copy(other.begin() + from, other.begin() + from + n, b.begin() + at);
        }
        return "splice@" + std::to_string(at) + "+" + std::to_string(n);
    }
    // Whole chunks dropped, repeated, or taken from another seed (out of order, foreign numbering).
    std::string splice_chunk(Bytes& b) {
        const std::vector<size_t> mine = chunk_starts(b);
        const Seed& donor = corpus_[rng_.below(corpus_.size())];
        const std::vector<size_t> theirs = chunk_starts(donor.bytes);
        if (mine.empty() || theirs.empty()) return splice_bytes(b);
        const size_t at = mine[rng_.below(mine.size())];
        switch (rng_.below(3)) {
        case 0: {
            const size_t n = chunk_span(b, at, mine);
            b.erase(b.begin() + at, b.begin() + at + n);
            return "drop-chunk@" + std::to_string(at);
        }
        case 1: {
            const size_t n = chunk_span(b, at, mine);
            Bytes copy(b.begin() + at, b.begin() + at + n);
            b.insert(b.begin() + at, copy.begin(), copy.end());
            return "repeat-chunk@" + std::to_string(at);
        }
        default: {
            const size_t from = theirs[rng_.below(theirs.size())];
            const size_t n = chunk_span(donor.bytes, from, theirs);
            b.insert(b.begin() + at, donor.bytes.begin() + from, donor.bytes.begin() + from + n);
            return "foreign-chunk@" + std::to_string(at);
        }
        }
    }
    // Length fields the reader must check before it allocates or loops.
    std::string huge_length(Bytes& b) {
        static const uint64_t values[] = {0xffffffffull,        0x80000000ull,
                                          0x7fffffffull,        0x40000000ull,
                                          0x10000001ull,        0xffffffffffffffffull,
                                          0x8000000000000000ull};
        const uint64_t v = values[rng_.below(std::size(values))];
        const std::vector<size_t> starts = chunk_starts(b);
        size_t at;
        size_t width = 4;
        if (!starts.empty() && rng_.chance(60)) {
            static const size_t fields[] = {12, 16, 20};  // record_count, raw_size, compressed_size
            at = starts[rng_.below(starts.size())] + fields[rng_.below(3)];
        } else if (b.size() >= f::kFileHeaderSize && rng_.chance(30)) {
            at = 12;  // trace_header_size
        } else {
            if (b.size() < 8) return set_byte(b);
            at = rng_.below(b.size() - 7) & ~size_t{3};
            width = rng_.chance(50) ? 8 : 4;
        }
        if (at + width > b.size()) return set_byte(b);
        std::memcpy(b.data() + at, &v, width);
        return "huge@" + std::to_string(at);
    }
    // Over a letter of some text when there is any, so strings become ill-formed UTF-8.
    std::string ill_formed_utf8(Bytes& b) {
        const std::string& bad = kIllFormedUtf8[rng_.below(kIllFormedUtf8.size())];
        size_t at = rng_.below(b.size() + 1);
        for (int tries = 0; tries < 64 && b.size() >= 4; ++tries) {
            const size_t p = rng_.below(b.size() - 3);
            if (std::all_of(b.begin() + p, b.begin() + p + 4,
                            [](uint8_t c) { return c >= 0x20 && c < 0x7f; })) {
                at = p;
                break;
            }
        }
        if (rng_.chance(70) && at + bad.size() <= b.size()) {
            std::copy(bad.begin(), bad.end(), b.begin() + at);  // same length: framing holds
        } else {
            b.insert(b.begin() + std::min(at, b.size()), bad.begin(), bad.end());
        }
        return "utf8@" + std::to_string(at);
    }
    // Decompress a chunk, mutate its raw bytes (records, frames, strings), compress it again.
    std::string edit_payload(Bytes& b) {
        const std::vector<size_t> starts = chunk_starts(b);
        if (starts.empty()) return flip_bit(b);
        const size_t at = starts[rng_.below(starts.size())];
        f::ChunkHeader h = f::load<f::ChunkHeader>(b.data() + at);
        if (h.raw_size > (16u << 20) ||
            at + f::kChunkHeaderSize + uint64_t(h.compressed_size) > b.size())
            return huge_length(b);
        Bytes raw(h.raw_size);
        const size_t got = ZSTD_decompress(raw.data(), raw.size(),
                                           b.data() + at + f::kChunkHeaderSize, h.compressed_size);
        if (ZSTD_isError(got)) return flip_bit(b);
        raw.resize(got);
        std::string what = "payload@" + std::to_string(at) + "[";
        for (size_t n = 1 + rng_.below(3); n > 0; --n) {
            switch (rng_.below(4)) {
            case 0: what += flip_bit(raw); break;
            case 1: what += set_byte(raw); break;
            case 2: what += ill_formed_utf8(raw); break;
            default: what += huge_length(raw); break;
            }
            what += n > 1 ? " " : "]";
        }
        Bytes packed(ZSTD_compressBound(raw.size()));
        const size_t n = ZSTD_compress(packed.data(), packed.size(), raw.data(), raw.size(), 1);
        if (ZSTD_isError(n)) return what;
        packed.resize(n);
        h.raw_size = uint32_t(raw.size());
        h.compressed_size = uint32_t(n);
        h.payload_checksum = f::checksum(packed.data(), n);
        h.header_checksum = f::chunk_header_checksum(h);
        Bytes chunk(sizeof h);
        std::memcpy(chunk.data(), &h, sizeof h);
        chunk.insert(chunk.end(), packed.begin(), packed.end());
        const size_t span = chunk_span(b, at, starts);
        b.erase(b.begin() + at, b.begin() + at + span);
        b.insert(b.begin() + at, chunk.begin(), chunk.end());
        return what;
    }

    const std::vector<Seed>& corpus_;
    Random rng_;
};

bool skipped(const std::string& name, const Settings& s) {
    return std::any_of(s.skip.begin(), s.skip.end(),
                       [&](const std::string& t) { return name.find(t) != std::string::npos; });
}

std::vector<Seed> load_seeds(const Settings& s) {
    std::vector<std::filesystem::path> files;
    for (const std::string& input : s.inputs) {
        std::error_code ec;
        if (std::filesystem::is_directory(input, ec)) {
            for (const auto& e : std::filesystem::recursive_directory_iterator(input, ec))
                if (e.is_regular_file()) files.push_back(e.path());
        } else if (std::filesystem::is_regular_file(input, ec)) {
            files.push_back(input);
        } else {
            std::fprintf(stderr, "%s: no seed file or folder '%s'\n", g_target, input.c_str());
            std::exit(2);
        }
    }
    std::sort(files.begin(),
              files.end());  // the same order every run: mutations repeat with --seed
    std::vector<Seed> seeds;
    for (const auto& path : files) {
        if (skipped(path.string(), s)) continue;
        std::ifstream in(path, std::ios::binary);
        Bytes bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
        if (bytes.size() > kMaxInputBytes) bytes.resize(kMaxInputBytes);
        seeds.push_back({path.string(), std::move(bytes)});
    }
    return seeds;
}

Settings parse(int argc, char** argv) {
    Settings s;
    for (int i = 1; i < argc; ++i) {
        const std::string a = argv[i];
        auto value = [&]() -> std::string {
            if (i + 1 >= argc) {
                std::fprintf(stderr, "%s: %s needs a value\n", g_target, a.c_str());
                std::exit(2);
            }
            return argv[++i];
        };
        if (a == "--seconds")
            s.seconds = std::stod(value());
        else if (a == "--input-seconds")
            s.input_seconds = std::stod(value());
        else if (a == "--rss-limit-mb")
            s.rss_limit_mb = std::stoull(value());
        else if (a == "--seed")
            s.seed = std::stoull(value());
        else if (a == "--findings")
            s.findings = value();
        else if (a == "--skip")
            s.skip.push_back(value());
        else if (a.rfind("--", 0) == 0) {
            std::fprintf(stderr, "%s: unknown option %s (see tests/fuzz/standalone_driver.cpp)\n",
                         g_target, a.c_str());
            std::exit(2);
        } else
            s.inputs.push_back(a);
    }
    return s;
}

}  // namespace

int main(int argc, char** argv) {
    std::snprintf(g_target, sizeof g_target, "%s",
                  std::filesystem::path(argv[0]).filename().c_str());
    const Settings s = parse(argc, argv);
    std::filesystem::create_directories(s.findings);
    std::snprintf(g_findings, sizeof g_findings, "%s", s.findings.c_str());
    std::vector<Seed> corpus = load_seeds(s);
    if (corpus.empty()) corpus.push_back({"(empty input)", {}});
    install_crash_handlers();
    std::thread(watch, std::cref(s)).detach();

    Bytes input;
    std::string history;
    uint64_t runs = 0;
    auto run_one = [&] {
        std::snprintf(g_history, sizeof g_history, "%s", history.c_str());
        g_input = &input;
        g_started_ns = Clock::now().time_since_epoch().count();
        LLVMFuzzerTestOneInput(input.data(), input.size());
        g_started_ns = 0;
        ++runs;
    };
    const auto start = Clock::now();
    for (const Seed& seed : corpus) {
        input = seed.bytes;
        history = seed.name + " (as it is)";
        run_one();
    }
    Mutator mutator(corpus, s.seed);
    while (std::chrono::duration<double>(Clock::now() - start).count() < s.seconds) {
        mutator.next(input, history);
        run_one();
    }
    std::printf(
        "%s: %llu inputs (%zu seeds, then mutations with --seed %llu) in %.1f s: no crash, no "
        "input over "
        "%.0f s or %llu MiB\n",
        g_target, (unsigned long long)runs, corpus.size(), (unsigned long long)s.seed,
        std::chrono::duration<double>(Clock::now() - start).count(), s.input_seconds,
        (unsigned long long)s.rss_limit_mb);
    return 0;
}
