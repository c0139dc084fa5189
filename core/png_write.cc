#include "core/png_write.h"

#include <zlib.h>

#include <algorithm>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <memory>
#include <string>
#include <vector>

#include "core/error.h"
#include "core/fs.h"
#include "core/parallel.h"

namespace mesoscan {
namespace {

void PutBe32(std::vector<uint8_t>* out, uint32_t v) {
  for (int s = 24; s >= 0; s -= 8) out->push_back(static_cast<uint8_t>(v >> s));
}

// Appends a chunk (length, type, data, CRC of type + data).
void PutChunk(std::vector<uint8_t>* out, const char* type, const uint8_t* data, size_t n) {
  PutBe32(out, static_cast<uint32_t>(n));
  const size_t at = out->size();
  out->insert(out->end(), type, type + 4);
  out->insert(out->end(), data, data + n);
  PutBe32(out, static_cast<uint32_t>(::crc32(0, out->data() + at, static_cast<uInt>(n + 4))));
}

struct Piece {
  std::vector<uint8_t> deflated;
  uLong adler = 1;
  uLong raw_size = 0;
  std::string error;
};

}  // namespace

void WritePng8Unfiltered(const std::filesystem::path& path, const ImageU8& image, int level) {
  const int w = image.width(), h = image.height(), nc = image.channels();
  MESOSCAN_CHECK(w > 0 && h > 0 && nc >= 1 && nc <= 4);
  level = std::clamp(level, 0, 9);
  const size_t row_bytes = 1 + static_cast<size_t>(w) * nc;  // the filter byte, then samples
  // Pieces of ~256 KB of rows: enough of them to share among the threads, each large enough
  // that its sync flush and its fresh start cost little (the dictionary keeps the matches).
  constexpr size_t kPieceBytes = size_t{256} << 10, kWindow = size_t{32} << 10;
  const int rows_per_piece = static_cast<int>(std::max<size_t>(1, kPieceBytes / row_bytes));
  const int pieces = (h + rows_per_piece - 1) / rows_per_piece;
  const int dict_rows = static_cast<int>((kWindow + row_bytes - 1) / row_bytes);
  std::vector<Piece> out(pieces);
  ParallelFor(pieces, [&](int64_t k) {
    Piece& p = out[k];
    const int y0 = static_cast<int>(k) * rows_per_piece, y1 = std::min(h, y0 + rows_per_piece);
    const int d0 = std::max(0, y0 - dict_rows);
    // Rows d0..y1 as PNG scan lines (filter byte 0, samples interleaved).
    std::vector<uint8_t> raw(static_cast<size_t>(y1 - d0) * row_bytes);
    for (int y = d0; y < y1; ++y) {
      uint8_t* line = raw.data() + static_cast<size_t>(y - d0) * row_bytes;
      line[0] = 0;
      for (int c = 0; c < nc; ++c) {
        const uint8_t* src = image.channel(c) + static_cast<size_t>(y) * w;
        for (int x = 0; x < w; ++x) line[1 + static_cast<size_t>(x) * nc + c] = src[x];
      }
    }
    const size_t dict_bytes = static_cast<size_t>(y0 - d0) * row_bytes;
    const uint8_t* in = raw.data() + dict_bytes;
    const size_t n = raw.size() - dict_bytes;
    p.raw_size = n;
    p.adler = ::adler32(1, in, static_cast<uInt>(n));
    z_stream z{};
    if (deflateInit2(&z, level, Z_DEFLATED, -15, 8, Z_DEFAULT_STRATEGY) != Z_OK) {
      p.error = "zlib deflateInit2 failed";
      return;
    }
    const size_t dict = std::min(dict_bytes, kWindow);
    if (dict > 0) deflateSetDictionary(&z, raw.data() + dict_bytes - dict, static_cast<uInt>(dict));
    p.deflated.resize(deflateBound(&z, n) + 64);
    z.next_in = const_cast<uint8_t*>(in);
    z.avail_in = static_cast<uInt>(n);
    const int flush = k + 1 == pieces ? Z_FINISH : Z_SYNC_FLUSH;
    size_t done = 0;
    for (;;) {
      z.next_out = p.deflated.data() + done;
      z.avail_out = static_cast<uInt>(p.deflated.size() - done);
      const int rc = deflate(&z, flush);
      done = p.deflated.size() - z.avail_out;
      if (rc == Z_STREAM_END ||
          (flush == Z_SYNC_FLUSH && rc == Z_OK && z.avail_out > 0 && z.avail_in == 0))
        break;
      if (rc != Z_OK && rc != Z_BUF_ERROR) {
        p.error = "zlib deflate failed";
        break;
      }
      p.deflated.resize(p.deflated.size() * 2);
    }
    p.deflated.resize(done);
    deflateEnd(&z);
  });
  for (const Piece& p : out)
    if (!p.error.empty())
      MESOSCAN_BAD_INPUT_AT(ErrorSite::File(path), "cannot write image (" << p.error << ")");

  // The file: signature, IHDR, the zlib stream (header, pieces, Adler-32) as IDAT chunks, IEND.
  std::vector<uint8_t> head = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1a, '\n'};
  std::vector<uint8_t> ihdr;
  PutBe32(&ihdr, static_cast<uint32_t>(w));
  PutBe32(&ihdr, static_cast<uint32_t>(h));
  static const uint8_t kColourType[5] = {0, 0, 4, 2, 6};
  ihdr.insert(ihdr.end(), {8, kColourType[nc], 0, 0, 0});
  PutChunk(&head, "IHDR", ihdr.data(), ihdr.size());
  // zlib header: deflate, 32 KB window, no dictionary, FLEVEL from the level, FCHECK.
  const unsigned flevel = level < 2 ? 0 : level < 6 ? 1 : level == 6 ? 2 : 3;
  unsigned cmf_flg = 0x78 * 256 + (flevel << 6);
  cmf_flg += 31 - cmf_flg % 31;
  uLong adler = 1;
  for (const Piece& p : out)
    adler = ::adler32_combine(adler, p.adler, static_cast<z_off_t>(p.raw_size));
  std::vector<uint8_t> zhead = {static_cast<uint8_t>(cmf_flg >> 8), static_cast<uint8_t>(cmf_flg)};
  std::vector<uint8_t> ztail;
  PutBe32(&ztail, static_cast<uint32_t>(adler));

  WriteFileChecked(path, [&](CheckedFile& f) {
    f.Write(head.data(), head.size());
    // One IDAT per piece (the zlib header rides in the first, the Adler-32 in the last): each
    // chunk's CRC covers its own bytes, computed here (~1 ms per MB).
    for (size_t k = 0; k < out.size(); ++k) {
      std::vector<uint8_t> chunk;
      const std::vector<uint8_t>& d = out[k].deflated;
      std::vector<uint8_t> data;
      const std::vector<uint8_t>* payload = &d;
      if (k == 0 || k + 1 == out.size()) {
        if (k == 0) data = zhead;
        data.insert(data.end(), d.begin(), d.end());
        if (k + 1 == out.size()) data.insert(data.end(), ztail.begin(), ztail.end());
        payload = &data;
      }
      PutBe32(&chunk, static_cast<uint32_t>(payload->size()));
      chunk.insert(chunk.end(), {'I', 'D', 'A', 'T'});
      uLong crc = ::crc32(0, chunk.data() + 4, 4);
      crc = ::crc32(crc, payload->data(), static_cast<uInt>(payload->size()));
      f.Write(chunk.data(), chunk.size());
      f.Write(payload->data(), payload->size());
      chunk.clear();
      PutBe32(&chunk, static_cast<uint32_t>(crc));
      f.Write(chunk.data(), 4);
    }
    std::vector<uint8_t> tail;
    PutChunk(&tail, "IEND", nullptr, 0);
    f.Write(tail.data(), tail.size());
  });
}

}  // namespace mesoscan
