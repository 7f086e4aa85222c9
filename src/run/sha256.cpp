#include "turncal/run/sha256.hpp"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <vector>

#if defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__))
#include <cpuid.h>
#include <immintrin.h>
#define TURNCAL_SHA_NI 1
#endif

namespace turncal::run {

// ---- the compression function (FIPS 180-4, sections 4.2.2 and 6.2.2) ----

namespace {

alignas(16) constexpr std::array<std::uint32_t, 64> kK = {
    0x428a2f98, 0x71374491, 0xb5c0fbcf, 0xe9b5dba5, 0x3956c25b, 0x59f111f1, 0x923f82a4, 0xab1c5ed5,
    0xd807aa98, 0x12835b01, 0x243185be, 0x550c7dc3, 0x72be5d74, 0x80deb1fe, 0x9bdc06a7, 0xc19bf174,
    0xe49b69c1, 0xefbe4786, 0x0fc19dc6, 0x240ca1cc, 0x2de92c6f, 0x4a7484aa, 0x5cb0a9dc, 0x76f988da,
    0x983e5152, 0xa831c66d, 0xb00327c8, 0xbf597fc7, 0xc6e00bf3, 0xd5a79147, 0x06ca6351, 0x14292967,
    0x27b70a85, 0x2e1b2138, 0x4d2c6dfc, 0x53380d13, 0x650a7354, 0x766a0abb, 0x81c2c92e, 0x92722c85,
    0xa2bfe8a1, 0xa81a664b, 0xc24b8b70, 0xc76c51a3, 0xd192e819, 0xd6990624, 0xf40e3585, 0x106aa070,
    0x19a4c116, 0x1e376c08, 0x2748774c, 0x34b0bcb5, 0x391c0cb3, 0x4ed8aa4a, 0x5b9cca4f, 0x682e6ff3,
    0x748f82ee, 0x78a5636f, 0x84c87814, 0x8cc70208, 0x90befffa, 0xa4506ceb, 0xbef9a3f7, 0xc67178f2};

constexpr std::uint32_t rotr(std::uint32_t x, int n) {
  return (x >> n) | (x << (32 - n));
}

#ifdef TURNCAL_SHA_NI
// The SHA extensions keep the eight working variables in two registers,
// (A, B, E, F) and (C, D, G, H), highest lane first; sha256rnds2 does two
// rounds, sha256msg1 and sha256msg2 the message schedule four words at a
// time (Intel SHA Extensions, 2013).
__attribute__((target("sha,sse4.1,ssse3"))) void blocks_sha_ni(std::array<std::uint32_t, 8>& h,
                                                               const unsigned char* p,
                                                               std::size_t blocks) {
  // each 32-bit word of the message is big-endian
  const __m128i bswap = _mm_set_epi64x(0x0c0d0e0f08090a0bLL, 0x0405060700010203LL);
  const __m128i dcba = _mm_loadu_si128(reinterpret_cast<const __m128i*>(h.data()));
  const __m128i hgfe = _mm_loadu_si128(reinterpret_cast<const __m128i*>(h.data() + 4));
  const __m128i cdab = _mm_shuffle_epi32(dcba, 0xB1);  // lanes B A D C
  const __m128i efgh = _mm_shuffle_epi32(hgfe, 0x1B);  // lanes H G F E
  __m128i abef = _mm_alignr_epi8(cdab, efgh, 8);       // lanes F E B A
  __m128i cdgh = _mm_blend_epi16(efgh, cdab, 0xF0);    // lanes H G D C
  for (; blocks > 0; --blocks, p += 64) {
    const __m128i abef0 = abef;
    const __m128i cdgh0 = cdgh;
    __m128i w[4];  // W[4i..4i+3] of the last four groups (a plain array: the type has attributes)
    for (std::size_t i = 0; i < 16; ++i) {
      __m128i m;
      if (i < 4) {
        m = _mm_shuffle_epi8(_mm_loadu_si128(reinterpret_cast<const __m128i*>(p + 16 * i)), bswap);
      } else {
        // W[t] = s1(W[t-2]) + W[t-7] + s0(W[t-15]) + W[t-16]
        const __m128i s0 = _mm_sha256msg1_epu32(w[(i - 4) & 3], w[(i - 3) & 3]);
        const __m128i t7 = _mm_alignr_epi8(w[(i - 1) & 3], w[(i - 2) & 3], 4);
        m = _mm_sha256msg2_epu32(_mm_add_epi32(s0, t7), w[(i - 1) & 3]);
      }
      w[i & 3] = m;
      const __m128i wk =
          _mm_add_epi32(m, _mm_load_si128(reinterpret_cast<const __m128i*>(kK.data() + 4 * i)));
      // two rounds each: what comes back is the new (A, B, E, F), and the
      // old one is the new (C, D, G, H); so after four the names hold again
      cdgh = _mm_sha256rnds2_epu32(cdgh, abef, wk);
      abef = _mm_sha256rnds2_epu32(abef, cdgh, _mm_shuffle_epi32(wk, 0x0E));
    }
    abef = _mm_add_epi32(abef, abef0);
    cdgh = _mm_add_epi32(cdgh, cdgh0);
  }
  const __m128i abef_r = _mm_shuffle_epi32(abef, 0x1B);  // lanes A B E F
  const __m128i ghcd = _mm_shuffle_epi32(cdgh, 0xB1);    // lanes G H C D
  _mm_storeu_si128(reinterpret_cast<__m128i*>(h.data()), _mm_blend_epi16(abef_r, ghcd, 0xF0));
  _mm_storeu_si128(reinterpret_cast<__m128i*>(h.data() + 4), _mm_alignr_epi8(ghcd, abef_r, 8));
}

bool cpu_has_sha_ni() {
  unsigned a = 0, b = 0, c = 0, d = 0;
  if (__get_cpuid(1, &a, &b, &c, &d) == 0) return false;
  const bool ssse3 = (c & bit_SSSE3) != 0;
  const bool sse41 = (c & bit_SSE4_1) != 0;
  if (__get_cpuid_count(7, 0, &a, &b, &c, &d) == 0) return false;
  const bool sha = (b & (1u << 29)) != 0;  // CPUID.(EAX=7,ECX=0):EBX.SHA
  return ssse3 && sse41 && sha;
}
#endif

}  // namespace

void detail::sha256_blocks_portable(std::array<std::uint32_t, 8>& h, const unsigned char* p,
                                    std::size_t blocks) {
  for (; blocks > 0; --blocks, p += 64) {
    std::array<std::uint32_t, 64> w{};
    for (std::size_t t = 0; t < 16; ++t)
      w[t] = static_cast<std::uint32_t>(p[4 * t]) << 24 |
             static_cast<std::uint32_t>(p[4 * t + 1]) << 16 |
             static_cast<std::uint32_t>(p[4 * t + 2]) << 8 |
             static_cast<std::uint32_t>(p[4 * t + 3]);
    for (std::size_t t = 16; t < 64; ++t) {
      const std::uint32_t s0 = rotr(w[t - 15], 7) ^ rotr(w[t - 15], 18) ^ (w[t - 15] >> 3);
      const std::uint32_t s1 = rotr(w[t - 2], 17) ^ rotr(w[t - 2], 19) ^ (w[t - 2] >> 10);
      w[t] = w[t - 16] + s0 + w[t - 7] + s1;
    }
    auto [a, b, c, d, e, f, g, hh] = h;
    for (std::size_t t = 0; t < 64; ++t) {
      const std::uint32_t t1 =
          hh + (rotr(e, 6) ^ rotr(e, 11) ^ rotr(e, 25)) + ((e & f) ^ (~e & g)) + kK[t] + w[t];
      const std::uint32_t t2 =
          (rotr(a, 2) ^ rotr(a, 13) ^ rotr(a, 22)) + ((a & b) ^ (a & c) ^ (b & c));
      hh = g;
      g = f;
      f = e;
      e = d + t1;
      d = c;
      c = b;
      b = a;
      a = t1 + t2;
    }
    h[0] += a;
    h[1] += b;
    h[2] += c;
    h[3] += d;
    h[4] += e;
    h[5] += f;
    h[6] += g;
    h[7] += hh;
  }
}

detail::Sha256Blocks detail::sha256_blocks_hardware() {
#ifdef TURNCAL_SHA_NI
  static const bool has = cpu_has_sha_ni();
  return has ? &blocks_sha_ni : nullptr;
#else
  return nullptr;
#endif
}

namespace {
/// The compression this process uses: the hardware's where there is one.
detail::Sha256Blocks compress() {
  static const detail::Sha256Blocks f = [] {
    const detail::Sha256Blocks hw = detail::sha256_blocks_hardware();
    return hw != nullptr ? hw : &detail::sha256_blocks_portable;
  }();
  return f;
}
}  // namespace

Sha256::Sha256()
    : h_{0x6a09e667, 0xbb67ae85, 0x3c6ef372, 0xa54ff53a,
         0x510e527f, 0x9b05688c, 0x1f83d9ab, 0x5be0cd19} {}

void Sha256::update(std::string_view data) {
  const auto* p = reinterpret_cast<const unsigned char*>(data.data());
  std::size_t n = data.size();
  bytes_ += n;
  if (fill_ > 0) {  // a block begun by an earlier piece
    const std::size_t take = std::min(n, 64 - fill_);
    std::copy(p, p + take, buf_.begin() + static_cast<long>(fill_));
    fill_ += take;
    p += take;
    n -= take;
    if (fill_ < 64) return;
    compress()(h_, buf_.data(), 1);
    fill_ = 0;
  }
  compress()(h_, p, n / 64);  // whole blocks straight from the input
  p += n / 64 * 64;
  n %= 64;
  std::copy(p, p + n, buf_.begin());
  fill_ = n;
}

std::string Sha256::hex() const {
  // the padding (FIPS 180-4, 5.1.1) on a copy, so the hash can go on
  std::array<std::uint32_t, 8> h = h_;
  std::array<unsigned char, 128> tail{};
  std::copy(buf_.begin(), buf_.begin() + static_cast<long>(fill_), tail.begin());
  tail[fill_] = 0x80;
  const std::size_t len = fill_ + 9 <= 64 ? 64 : 128;
  const std::uint64_t bits = bytes_ * 8;
  for (std::size_t k = 0; k < 8; ++k)
    tail[len - 1 - k] = static_cast<unsigned char>(bits >> (8 * k));
  compress()(h, tail.data(), len / 64);
  std::string out;
  char b[9];
  for (std::uint32_t v : h) {
    std::snprintf(b, sizeof b, "%08x", v);
    out += b;
  }
  return out;
}

std::string sha256_hex(std::string_view data) {
  Sha256 s;
  s.update(data);
  return s.hex();
}

Result<FileDigest> sha256_file(const std::string& path, CountLines count, Links links) {
  // never blocking, and only a regular file: a FIFO in a log's place would
  // hold the reader up (or take bytes another reader waits for)
  const int fd = ::open(
      path.c_str(), O_RDONLY | O_NONBLOCK | O_CLOEXEC | (links == Links::Refuse ? O_NOFOLLOW : 0));
  if (fd < 0) return make_error("cannot read " + path + ": " + std::strerror(errno));
  struct stat st {};
  const bool stat_ok = ::fstat(fd, &st) == 0;
  const int stat_err = errno;
  if (!stat_ok || !S_ISREG(st.st_mode)) {
    (void)::close(fd);  // read only: nothing of it to lose
    return make_error("cannot read " + path + ": " +
                      (stat_ok ? "not a regular file" : std::strerror(stat_err)));
  }
  std::FILE* f = ::fdopen(fd, "rb");
  if (f == nullptr) {
    const int err = errno;
    (void)::close(fd);
    return make_error("cannot read " + path + ": " + std::strerror(err));
  }
  Sha256 s;
  std::uint64_t lines = 0;
  std::vector<char> chunk(std::size_t{1} << 20);
  std::size_t n;
  while ((n = std::fread(chunk.data(), 1, chunk.size(), f)) > 0) {
    const std::string_view v(chunk.data(), n);
    s.update(v);
    if (count == CountLines::No) continue;
    // memchr, vectorised in the C library: twice std::count's speed here
    const char* end = chunk.data() + n;
    for (const char* p = chunk.data();
         (p = static_cast<const char*>(std::memchr(p, '\n', static_cast<std::size_t>(end - p)))) !=
         nullptr;
         ++p)
      ++lines;
  }
  const bool bad = std::ferror(f) != 0;
  std::fclose(f);
  if (bad) return make_error("cannot read " + path);
  FileDigest d{s.hex(), std::nullopt};
  if (count == CountLines::Yes) d.lines = lines;
  return d;
}

}  // namespace turncal::run
