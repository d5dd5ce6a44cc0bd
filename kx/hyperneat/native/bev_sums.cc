// kx_bev_sums: the sums of kx.hyperneat.bev.sparse_outputs for the authors' Bird's Eye View image, one lane
// at a time, as an XLA FFI custom call on CPU.
//
// For each lane l (genome g = index[l]) and each requested output row o = rows[r, l]:
//   sum = b[g, o], then sum = sum + value * w[g, o, cell] for each entry of the lane's image in the order of
//   kx.hyperneat.bev.sparse_image: the K keepers, the T takers, then each path (the holder's teammates in
//   keeper order, then the takers) step by step, steps 1 .. n - 1 only (padding adds 0 * w: left out).
// A lane that is not busy adds 0 * w[g, o, holder's cell] for each agent entry instead (what the compiled
// policy does there), so that every output is the compiled policy's bit for bit.
//
// `fused`: whether each multiply-add rounds once (std::fma) or twice (a product, then a sum). XLA CPU fuses
// the policy's chain into fused multiply-adds under its default flags and not at backend optimisation level
// 0; kx.hyperneat.native probes which the process's flags do and passes it here.
//
// The image arithmetic is the policy's (kx.hyperneat.bev._image_parts, the "authors" branch): every operation
// is one IEEE operation (a division, a square root, an addition), and the digital line's floor is exact
// whichever way i * slope + 0.501 is rounded (bev.ROUND_OFFSET's comment).
#include <algorithm>
#include <cmath>
#include <cstdint>

#include "xla/ffi/api/ffi.h"

namespace ffi = xla::ffi;

namespace {

constexpr int kMaxAgents = 64;
constexpr int kMaxEntries = 64 * 62 + 64;

struct Image {
  int32_t cell[kMaxEntries];
  float value[kMaxEntries];
  int32_t size;
};

struct Lanes {
  int64_t n;  // lanes
  int32_t k, t, width;
  const int32_t *kx, *ky, *tx, *ty, *holder;
  const bool* busy;
  // the image's values (kx.sim.observe.BEV_AUTHORS_*) and the digital line's offset (bev.ROUND_OFFSET),
  // passed by the caller so that they have one home
  float holder_value, teammate_value, taker_value, round_offset;
};

inline int32_t Sign(int32_t v) { return (v > 0) - (v < 0); }

// Calls add(value, cell) for each entry of lane l's image in order: its K keepers, its T takers, then each
// path (the holder's teammates in keeper order, then the takers) step by step, steps 1 .. n - 1. An idle lane:
// its agents' entries at the holder's cell with value 0, no path steps.
template <typename Add>
inline void ForEachEntry(const Lanes& s, int64_t l, Add&& add) {
  const int64_t n = s.n;
  const int32_t h = std::max(s.holder[l], 0);
  const int32_t sx = s.kx[h * n + l], sy = s.ky[h * n + l], w = s.width;
  const int32_t hc = sx + w * sy;
  if (!s.busy[l]) {
    for (int32_t a = 0; a < s.k + s.t; ++a) add(0.0f, hc);
    return;
  }
  for (int32_t i = 0; i < s.k; ++i) add(i == h ? s.holder_value : s.teammate_value, s.kx[i * n + l] + w * s.ky[i * n + l]);
  for (int32_t j = 0; j < s.t; ++j) add(s.taker_value, s.tx[j * n + l] + w * s.ty[j * n + l]);
  for (int32_t p = 0; p < s.k - 1 + s.t; ++p) {
    int32_t x, y;
    float sg;
    if (p < s.k - 1) {
      const int32_t mate = p + (p >= h ? 1 : 0);
      x = s.kx[mate * n + l], y = s.ky[mate * n + l], sg = 1.0f;
    } else {
      x = s.tx[(p - (s.k - 1)) * n + l], y = s.ty[(p - (s.k - 1)) * n + l], sg = -1.0f;
    }
    const int32_t dx = x - sx, dy = y - sy, adx = std::abs(dx), ady = std::abs(dy);
    const int32_t steps = std::max(adx, ady);
    const bool x_major = adx >= ady;
    const int32_t major = x_major ? Sign(dx) : w * Sign(dy), minor = x_major ? w : 1;
    const float slope = static_cast<float>(x_major ? dy : dx) / static_cast<float>(std::max(steps, 1));
    const float value = sg / (1.0f + std::sqrt(static_cast<float>(dx * dx + dy * dy)));
    for (int32_t i = 1; i < steps; ++i)
      add(value, hc + i * major + minor * static_cast<int32_t>(std::floor(static_cast<float>(i) * slope + s.round_offset)));
  }
}

// The lane's image stored as a list (for many rows: computed once, read by each block of rows).
void ImageOf(const Lanes& s, int64_t l, Image& out) {
  int32_t e = 0;
  ForEachEntry(s, l, [&](float v, int32_t c) {
    out.cell[e] = c;
    out.value[e] = v;
    ++e;
  });
  out.size = e;
}

template <bool kFused>
inline float MultiplyAdd(float v, float w, float acc) {
  if constexpr (kFused) {
    return std::fma(v, w, acc);
  } else {
    return acc + v * w;  // two roundings: kx.hyperneat.native compiles with -ffp-contract=off, so no fma is formed
  }
}

// R output rows of one lane, their chains interleaved (R independent multiply-add chains per entry).
template <bool kFused, int R>
inline void Chains(const float* const* row, float* acc, const Image& img) {
  for (int32_t e = 0; e < img.size; ++e) {
    const float v = img.value[e];
    const int32_t c = img.cell[e];
    for (int r = 0; r < R; ++r) acc[r] = MultiplyAdd<kFused>(v, row[r][c], acc[r]);
  }
}

// One lane's sums, each entry applied to the R rows' chains as it is computed (the image never stored).
template <bool kFused, int R>
inline void LaneSums(const Lanes& s, int64_t l, const float* const* row, float* acc) {
  ForEachEntry(s, l, [&](float v, int32_t c) {
    for (int r = 0; r < R; ++r) acc[r] = MultiplyAdd<kFused>(v, row[r][c], acc[r]);
  });
}

template <bool kFused>
void Sums(const Lanes& s, const float* w, const float* b, const int32_t* index, const int32_t* rows, int64_t n_rows,
          int64_t n_cells, float* out) {
  constexpr int kBlock = 8;
  auto start = [&](int64_t l, int64_t r0, int64_t m, const float** row, float* acc) {
    const int64_t g = index[l];
    for (int64_t r = 0; r < m; ++r) {
      const int64_t o = g * n_cells + rows[(r0 + r) * s.n + l];
      row[r] = w + o * n_cells;
      acc[r] = b[o];
    }
  };
  auto store = [&](int64_t l, int64_t r0, int64_t m, const float* acc) {
    for (int64_t r = 0; r < m; ++r) out[(r0 + r) * s.n + l] = acc[r];
  };
  if (n_rows >= 3 && n_rows <= 6) {  // the keepers' cells of 3v2 .. 6v4: each entry applied as it is computed
    for (int64_t l = 0; l < s.n; ++l) {
      const float* row[kBlock];
      float acc[kBlock];
      start(l, 0, n_rows, row, acc);
      switch (n_rows) {
        case 3: LaneSums<kFused, 3>(s, l, row, acc); break;
        case 4: LaneSums<kFused, 4>(s, l, row, acc); break;
        case 5: LaneSums<kFused, 5>(s, l, row, acc); break;
        default: LaneSums<kFused, 6>(s, l, row, acc);
      }
      store(l, 0, n_rows, acc);
    }
    return;
  }
  static thread_local Image img;  // any other count of rows: the lane's image once, then 8 rows at a time
  for (int64_t l = 0; l < s.n; ++l) {
    ImageOf(s, l, img);
    for (int64_t r0 = 0; r0 < n_rows; r0 += kBlock) {
      const int64_t m = std::min<int64_t>(kBlock, n_rows - r0);
      const float* row[kBlock];
      float acc[kBlock];
      start(l, r0, m, row, acc);
      if (m == kBlock) {
        Chains<kFused, kBlock>(row, acc, img);
      } else {
        for (int64_t r = 0; r < m; ++r) Chains<kFused, 1>(row + r, acc + r, img);
      }
      store(l, r0, m, acc);
    }
  }
}

}  // namespace

static ffi::Error BevSumsImpl(ffi::Buffer<ffi::F32> w, ffi::Buffer<ffi::F32> b, ffi::Buffer<ffi::S32> index,
                              ffi::Buffer<ffi::S32> rows, ffi::Buffer<ffi::S32> keeper_x,
                              ffi::Buffer<ffi::S32> keeper_y, ffi::Buffer<ffi::S32> taker_x,
                              ffi::Buffer<ffi::S32> taker_y, ffi::Buffer<ffi::S32> holder,
                              ffi::Buffer<ffi::PRED> busy, int64_t width, bool fused, float holder_value,
                              float teammate_value, float taker_value, float round_offset,
                              ffi::ResultBuffer<ffi::F32> out) {
  const int64_t lanes = index.element_count();
  if (lanes == 0) return ffi::Error::Success();
  const int64_t n_cells = width * width;
  const int64_t k = keeper_x.element_count() / lanes, t = taker_x.element_count() / lanes;
  if (k < 2 || k + t > kMaxAgents || width < 3 || width > 63)
    return ffi::Error::InvalidArgument("kx_bev_sums: needs 2..64 agents with at least 2 keepers, width 3..63");
  if (w.element_count() % (n_cells * n_cells) != 0 || b.element_count() * n_cells != w.element_count())
    return ffi::Error::InvalidArgument("kx_bev_sums: the table is not [G, N, N] and [G, N] with N = width^2");
  const Lanes s{lanes, static_cast<int32_t>(k), static_cast<int32_t>(t), static_cast<int32_t>(width),
                keeper_x.typed_data(), keeper_y.typed_data(), taker_x.typed_data(), taker_y.typed_data(),
                holder.typed_data(), busy.typed_data(), holder_value, teammate_value, taker_value, round_offset};
  const int64_t n_rows = rows.element_count() / lanes;
  if (fused) {
    Sums<true>(s, w.typed_data(), b.typed_data(), index.typed_data(), rows.typed_data(), n_rows, n_cells,
               out->typed_data());
  } else {
    Sums<false>(s, w.typed_data(), b.typed_data(), index.typed_data(), rows.typed_data(), n_rows, n_cells,
                out->typed_data());
  }
  return ffi::Error::Success();
}

XLA_FFI_DEFINE_HANDLER_SYMBOL(KxBevSums, BevSumsImpl,
                              ffi::Ffi::Bind()
                                  .Arg<ffi::Buffer<ffi::F32>>()   // w [G, N, N]
                                  .Arg<ffi::Buffer<ffi::F32>>()   // b [G, N]
                                  .Arg<ffi::Buffer<ffi::S32>>()   // index [*B]
                                  .Arg<ffi::Buffer<ffi::S32>>()   // rows [R, *B]
                                  .Arg<ffi::Buffer<ffi::S32>>()   // keeper_x [K, *B]
                                  .Arg<ffi::Buffer<ffi::S32>>()   // keeper_y [K, *B]
                                  .Arg<ffi::Buffer<ffi::S32>>()   // taker_x [T, *B]
                                  .Arg<ffi::Buffer<ffi::S32>>()   // taker_y [T, *B]
                                  .Arg<ffi::Buffer<ffi::S32>>()   // holder [*B]
                                  .Arg<ffi::Buffer<ffi::PRED>>()  // busy [*B]
                                  .Attr<int64_t>("width")
                                  .Attr<bool>("fused")
                                  .Attr<float>("holder_value")
                                  .Attr<float>("teammate_value")
                                  .Attr<float>("taker_value")
                                  .Attr<float>("round_offset")
                                  .Ret<ffi::Buffer<ffi::F32>>());  // sums [R, *B]
