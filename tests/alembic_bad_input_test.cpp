// Bad input gets a clear pstream::Error naming the file, where, and what was expected — never a
// crash, a hang or an allocation the file does not justify.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <string>

#include "ogawa_builder.hpp"
#include "particlestream/alembic.hpp"
#include "particlestream/alembic_describe.hpp"
#include "test_util.hpp"

namespace {

using namespace pstream;
using test::OgawaBuilder;

// Reads every sample of every scalar and array property below `compound`.
void read_all_samples(const alembic::Property& compound) {
  for (std::size_t i = 0; i < compound.child_count(); ++i) {
    const alembic::Property p = compound.child(i);
    if (p.is_compound()) {
      read_all_samples(p);
      continue;
    }
    for (std::uint32_t s = 0; s < p.header().num_samples; ++s) (void)p.sample(s);
  }
}

std::string open_error(const std::vector<std::byte>& bytes, const std::string& name = "bad.abc") {
  try {
    const auto a = alembic::Archive::from_memory(bytes, name);
    (void)alembic::describe_json(a);
    for (const auto& o : a.objects()) read_all_samples(o.properties());
  } catch (const Error& e) {
    return e.what();
  }
  return "";
}

void expect_error(const std::vector<std::byte>& bytes, const std::string& fragment) {
  const std::string message = open_error(bytes);
  ASSERT_FALSE(message.empty()) << "no error for input that should fail with: " << fragment;
  EXPECT_NE(message.find("bad.abc"), std::string::npos) << message;
  EXPECT_NE(message.find(fragment), std::string::npos) << message;
}

// A valid archive: a top object with one child "obj" holding one float32 array property "P".
struct ValidArchive {
  OgawaBuilder b;
  std::uint64_t root = 0;
  std::string prop_headers;  // the packed header of "P"
  explicit ValidArchive(std::string_view sample_payload = std::string(16, 'k') + std::string(12, '\0'),
                        std::string_view dims = "") {
    const std::uint64_t sample = b.data(sample_payload);
    const std::uint64_t sample_dims = b.data(dims);
    const std::uint64_t p_group = b.group({sample, sample_dims});
    // info: array (2), size hint 0 (1-byte fields), pod float32 (10), constant, extent 3, metadata 0
    const std::uint32_t info = 2u | (10u << 4) | 0x800u | (3u << 12);
    prop_headers = OgawaBuilder::le32(info) + std::string(1, '\1') + std::string(1, '\1') + "P";
    const std::uint64_t props = b.group({p_group, b.data(prop_headers)});
    const std::uint64_t obj = b.group({props, b.data(OgawaBuilder::object_headers({}))});
    const std::uint64_t top = b.group({0, obj, b.data(OgawaBuilder::object_headers({"obj"}))});
    root = b.alembic_root(top);
  }
};

TEST(AlembicBadInput, BuilderArchiveIsValid) {
  ValidArchive v;
  const auto bytes = v.b.finish(v.root);
  const auto a = alembic::Archive::from_memory(bytes, "ok.abc");
  const auto obj = a.find("/obj");
  ASSERT_TRUE(obj.has_value());
  const auto P = obj->properties().find("P");
  ASSERT_TRUE(P.has_value());
  EXPECT_EQ(P->sample(0).size(), 1u);
}

TEST(AlembicBadInput, Hdf5BackendNamesTheBackendAndTheFix) {
  try {
    (void)alembic::Archive::open(test::data_path("alembic/points_hdf5_backend.abc"));
    FAIL() << "HDF5 archive was accepted";
  } catch (const Error& e) {
    const std::string m = e.what();
    EXPECT_NE(m.find("points_hdf5_backend.abc"), std::string::npos) << m;
    EXPECT_NE(m.find("HDF5"), std::string::npos) << m;
    EXPECT_NE(m.find("re-export it with the Ogawa backend"), std::string::npos) << m;
  }
  const auto r = test::run_cli("info '" + test::data_path("alembic/points_hdf5_backend.abc") + "'");
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.output.find("HDF5"), std::string::npos) << r.output;
}

TEST(AlembicBadInput, EmptyFile) {
  expect_error({}, "empty file");
  const auto path = std::filesystem::temp_directory_path() / "pstream_empty.abc";
  std::ofstream(path).close();
  const auto r = test::run_cli("info '" + path.string() + "'");
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.output.find("empty file"), std::string::npos) << r.output;
  std::filesystem::remove(path);
}

TEST(AlembicBadInput, NotAnAlembicFile) {
  const std::string text = "ply\nformat ascii 1.0\nelement vertex 0\nend_header\n";
  std::vector<std::byte> bytes(text.size());
  std::memcpy(bytes.data(), text.data(), text.size());
  expect_error(bytes, "is a PLY file, not an Alembic archive");
  const std::string other = "GIF89a and then some more bytes";
  bytes.assign(reinterpret_cast<const std::byte*>(other.data()),
               reinterpret_cast<const std::byte*>(other.data() + other.size()));
  expect_error(bytes, "not an Alembic file");
}

TEST(AlembicBadInput, FileStillBeingWritten) {
  ValidArchive v;
  expect_error(v.b.finish(v.root, 0x00), "still being written");
}

TEST(AlembicBadInput, WrongVersion) {
  ValidArchive v;
  auto bytes = v.b.finish(v.root);
  bytes[7] = std::byte{2};
  expect_error(bytes, "unsupported Ogawa version");
}

TEST(AlembicBadInput, EveryTruncationOfARealFileFailsCleanly) {
  const auto full = test::read_bytes(test::data_path("alembic/points_widths_constant.abc"));
  ASSERT_GT(full.size(), 1000u);
  for (std::size_t size : {std::size_t{1}, std::size_t{15}, std::size_t{16}, std::size_t{17}, full.size() / 4,
                           full.size() / 2, full.size() - 33, full.size() - 1}) {
    std::vector<std::byte> cut(full.begin(), full.begin() + static_cast<std::ptrdiff_t>(size));
    const std::string message = open_error(cut);
    EXPECT_FALSE(message.empty()) << "truncated to " << size << " bytes but accepted";
    EXPECT_NE(message.find("offset"), std::string::npos) << message;
  }
}

TEST(AlembicBadInput, RootOffsetPastTheEnd) {
  ValidArchive v;
  auto bytes = v.b.finish(v.root);
  const std::uint64_t bad = bytes.size() + 1000;
  std::memcpy(bytes.data() + 8, &bad, 8);
  expect_error(bytes, "past the end of the file");
}

TEST(AlembicBadInput, GroupClaimingMoreChildrenThanTheFileHolds) {
  ValidArchive v;
  auto bytes = v.b.finish(v.root);
  const std::uint64_t huge = 1ull << 60;  // must not become an allocation
  std::memcpy(bytes.data() + v.root, &huge, 8);
  expect_error(bytes, "claims 1152921504606846976 children");
}

TEST(AlembicBadInput, DataBlockSizePastTheEnd) {
  OgawaBuilder b;
  const std::uint64_t top = b.group({0, b.data(OgawaBuilder::object_headers({}))});
  const std::uint64_t root = b.alembic_root(top);
  auto bytes = b.finish(root);
  // The first data block (the file version) is at offset 16: make its size absurd.
  const std::uint64_t huge = 1ull << 40;
  std::memcpy(bytes.data() + 16, &huge, 8);
  expect_error(bytes, "runs past the end of the file");
}

TEST(AlembicBadInput, CycleInTheGroupGraph) {
  OgawaBuilder b;
  // The top object's only child object group is the top object group itself.
  const std::uint64_t headers = b.data(OgawaBuilder::object_headers({"loop"}));
  const std::uint64_t top = b.next_offset();
  const std::uint64_t top_again = b.group({0, top, headers});
  ASSERT_EQ(top, top_again);
  expect_error(b.finish(b.alembic_root(top)), "reached twice");
}

TEST(AlembicBadInput, ObjectHeadersDisagreeWithChildGroups) {
  OgawaBuilder b;
  const std::uint64_t top = b.group({0, b.data(OgawaBuilder::object_headers({"a", "b"}))});
  expect_error(b.finish(b.alembic_root(top)), "headers describe more");
}

TEST(AlembicBadInput, ArraySampleSizeNotAMultipleOfItsType) {
  ValidArchive v(std::string(16, 'k') + std::string(13, '\0'));  // 13 bytes: not float32 x3
  expect_error(v.b.finish(v.root), "not a multiple of 12");
}

TEST(AlembicBadInput, DimensionsDisagreeWithData) {
  ValidArchive v(std::string(16, 'k') + std::string(12, '\0'), OgawaBuilder::le64u(1000000));
  expect_error(v.b.finish(v.root), "dimensions say 1000000 elements");
}

TEST(AlembicBadInput, InvalidPodType) {
  ValidArchive v;
  auto bytes = v.b.finish(v.root);
  // Find the property header ("P" info word) and set its POD to 15.
  const std::string needle = v.prop_headers;
  auto it = std::search(bytes.begin(), bytes.end(), needle.begin(), needle.end(),
                        [](std::byte a, char c) { return a == static_cast<std::byte>(c); });
  ASSERT_NE(it, bytes.end());
  *(it) = static_cast<std::byte>(static_cast<unsigned>(*it) | 0xF0);
  expect_error(bytes, "invalid POD type 15");
}

}  // namespace
