#include "contract/bounded_decode.h"

#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cctype>
#include <climits>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <functional>
#include <map>
#include <new>
#include <random>
#include <regex>
#include <set>
#include <sstream>
#include <string>
#include <type_traits>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <stackgen/camera_info.hpp>
#include <stackgen/config_text.hpp>
#include <stackgen/credit.hpp>
#include <stackgen/header.hpp>
#include <stackgen/image.hpp>
#include <stackgen/instance.hpp>
#include <stackgen/labels.hpp>
#include <stackgen/model.hpp>
#include <stackgen/resend_request.hpp>
#include <stackgen/scene.hpp>
#include <stackgen/status.hpp>

namespace stackgen {
namespace {

// the types that have their own DecodeBounded specialisation (contract/bounded_decode.h)
const std::set<std::string> kSpecialised = {"scene", "labels", "image", "resend_request", "model"};

constexpr int kWidth = 32;
constexpr int kHeight = 24;

template <typename Message>
std::vector<uint8_t> Encode(const Message& message) {
  std::vector<uint8_t> bytes(static_cast<size_t>(message.getEncodedSize()));
  EXPECT_EQ(message.encode(bytes.data(), 0, static_cast<int>(bytes.size())),
            static_cast<int>(bytes.size()));
  return bytes;
}

void PutInt32(std::vector<uint8_t>* bytes, size_t offset, int32_t value) {
  const uint32_t bits = static_cast<uint32_t>(value);
  for (int i = 0; i < 4; ++i) (*bytes)[offset + i] = static_cast<uint8_t>(bits >> (24 - 8 * i));
}

pose MakePose(double x, double y, double z) {
  pose out{};
  out.translation_mm[0] = x;
  out.translation_mm[1] = y;
  out.translation_mm[2] = z;
  for (int i = 0; i < 9; ++i) out.rotation[i] = (i % 4 == 0) ? 1.0 : 0.0;
  out.quaternion_wxyz[0] = 1.0;
  return out;
}

instance MakeInstance(int32_t id, const std::string& class_name, const std::string& visib_rle,
                      const std::string& obj_rle) {
  instance out{};
  out.instance_id = id;
  out.class_id = 1;
  out.class_name = class_name;
  out.camera_from_object = MakePose(1.5 * id, -2.0, 400.0 + id);
  out.world_from_object = MakePose(10.0 * id, 20.0, 5.0);
  out.posture_deg[0] = 30.0 * id;
  out.posture_deg[1] = -45.0;
  out.posture_deg[2] = 179.5;
  out.resting_face = id % 3;
  for (int i = 0; i < 4; ++i) {
    out.bbox_obj[i] = id + i;
    out.bbox_visib[i] = id + i / 2;
  }
  out.px_count_all = 120 * id;
  out.px_count_visib = 100 * id;
  out.visib_fract = 100.0 / 120.0;
  out.annotated = 1;
  out.ignored = 0;
  out.mask_visib_rle = visib_rle;
  out.mask_obj_rle = obj_rle;
  return out;
}

image MakeRawImage(int8_t pixel_format, int bytes_per_pixel) {
  image out{};
  out.width = kWidth;
  out.height = kHeight;
  out.pixel_format = pixel_format;
  out.encoding = image::ENCODING_RAW;
  for (int i = 0; i < kWidth * kHeight * bytes_per_pixel; ++i) {
    out.data.push_back(static_cast<uint8_t>(i * 7));
  }
  out.size = static_cast<int32_t>(out.data.size());
  return out;
}

// a cv::Mat of `type` with a gradient in it.
cv::Mat Pattern(int type) {
  cv::Mat mat(kHeight, kWidth, type);
  for (int y = 0; y < kHeight; ++y) {
    for (int x = 0; x < kWidth; ++x) {
      if (type == CV_16UC1) {
        mat.at<uint16_t>(y, x) = static_cast<uint16_t>(1000 + 37 * x + 501 * y);
      } else if (type == CV_8UC1) {
        mat.at<uint8_t>(y, x) = static_cast<uint8_t>(5 * x + 3 * y);
      } else {
        mat.at<cv::Vec3b>(y, x) =
            cv::Vec3b(static_cast<uint8_t>(5 * x), static_cast<uint8_t>(9 * y), 200);
      }
    }
  }
  return mat;
}

// `mat` as a PNG or JPEG image message (`extension` ".png" or ".jpg").
image MakeEncodedImage(const cv::Mat& mat, int8_t pixel_format, const std::string& extension) {
  image out{};
  out.width = mat.cols;
  out.height = mat.rows;
  out.pixel_format = pixel_format;
  out.encoding = extension == ".png" ? image::ENCODING_PNG : image::ENCODING_JPEG;
  EXPECT_TRUE(cv::imencode(extension, mat, out.data));
  out.size = static_cast<int32_t>(out.data.size());
  return out;
}

scene MakeScene() {
  scene out{};
  out.header.seq = 41;
  out.header.generator_id = 2;
  out.header.seed = 0x5eed;
  out.header.utime = 1700000000000000;
  out.camera.width = kWidth;
  out.camera.height = kHeight;
  out.camera.fx = out.camera.fy = 30.0;
  out.camera.cx = 16.0;
  out.camera.cy = 12.0;
  out.camera.world_from_camera = MakePose(0, 0, 800);
  out.camera.depth_scale_mm = 0.1;
  out.instances = {MakeInstance(1, "connector", "52=1O2N1O1O0000001O0O1N2O0O2M`4", "4]1"),
                   MakeInstance(2, "connector", "o04d0N2O1O00001N2N3L", "o04e0L4L4K"),
                   MakeInstance(3, "bolt", "", "`7;")};
  out.num_instances = static_cast<int32_t>(out.instances.size());
  out.color = MakeRawImage(image::PIXEL_RGB8, 3);
  out.depth = MakeEncodedImage(Pattern(CV_16UC1), image::PIXEL_DEPTH16, ".png");
  out.instance_map = MakeEncodedImage(Pattern(CV_16UC1), image::PIXEL_INSTANCE16, ".png");
  return out;
}

labels LabelsOf(const scene& s) {
  labels out{};
  out.header = s.header;
  out.camera = s.camera;
  out.num_instances = s.num_instances;
  out.instances = s.instances;
  return out;
}

// byte offsets of fields in the encoding of MakeScene()
size_t NumInstancesOffset(const scene& s) {
  return 8 +
         static_cast<size_t>(s.header._getEncodedSizeNoHash() + s.camera._getEncodedSizeNoHash());
}
size_t FirstClassNameLengthOffset(const scene& s) { return NumInstancesOffset(s) + 4 + 8; }
size_t NumSuctionGraspsOffset(const scene& s) {
  size_t offset = NumInstancesOffset(s) + 4;
  for (const instance& i : s.instances) offset += static_cast<size_t>(i._getEncodedSizeNoHash());
  return offset;
}
size_t NumJawGraspsOffset(const scene& s) {
  size_t offset = NumSuctionGraspsOffset(s) + 4;
  for (const suction_grasp& g : s.suction_grasps) {
    offset += static_cast<size_t>(g._getEncodedSizeNoHash());
  }
  return offset;
}
size_t ColorOffset(const scene& s) {
  size_t offset = NumJawGraspsOffset(s) + 4;
  for (const jaw_grasp& g : s.jaw_grasps) offset += static_cast<size_t>(g._getEncodedSizeNoHash());
  return offset;
}
constexpr size_t kImageWidth = 0, kImageHeight = 4, kImagePixelFormat = 8, kImageSize = 10;

// DecodeBounded with default limits; the reason in `*why`.
template <typename Message>
bool Decode(const std::vector<uint8_t>& bytes, Message* out, std::string* why,
            const DecodeLimits& limits = {}) {
  return DecodeBounded(bytes.data(), bytes.size(), limits, out, why);
}

// what a forked child reported: its wait status and the text it sent back.
struct ChildResult {
  int status = 0;
  std::string text;
  bool ExitedZero() const { return WIFEXITED(status) && WEXITSTATUS(status) == 0; }
  std::string Describe() const {
    std::ostringstream out;
    if (WIFSIGNALED(status)) {
      out << "killed by signal " << WTERMSIG(status);
    } else {
      out << "exit " << WEXITSTATUS(status);
    }
    return out.str() + ", said \"" + text + "\"";
  }
};

#if defined(__SANITIZE_ADDRESS__) || defined(__SANITIZE_THREAD__)
constexpr bool kSanitized = true;
#elif defined(__has_feature)
#if __has_feature(address_sanitizer) || __has_feature(thread_sanitizer) || \
    __has_feature(memory_sanitizer)
constexpr bool kSanitized = true;
#else
constexpr bool kSanitized = false;
#endif
#else
constexpr bool kSanitized = false;
#endif

// the address space this process uses now (bytes).
size_t AddressSpaceNow() {
  std::ifstream statm("/proc/self/statm");
  size_t pages = 0;
  statm >> pages;
  return pages * static_cast<size_t>(sysconf(_SC_PAGESIZE));
}

// runs `body` in a forked child whose address space may grow by at most 1 GiB over what this
// process uses now; the child sends back what `body` returns and exits 0, so a crash or an
// uncaught exception shows in the status.
ChildResult RunWithAddressLimit(const std::function<std::string()>& body) {
  int fds[2];
  if (pipe(fds) != 0) return {-1, "pipe failed"};
  const size_t limit = AddressSpaceNow() + (size_t{1} << 30);
  const pid_t pid = fork();
  if (pid < 0) {
    close(fds[0]);
    close(fds[1]);
    return {-1, "fork failed"};
  }
  if (pid == 0) {
    close(fds[0]);
    // (sanitizers reserve terabytes of address space: there the child runs without the limit)
    const rlimit address_space = {limit, limit};
    if (!kSanitized && setrlimit(RLIMIT_AS, &address_space) != 0) _exit(90);
    const std::string text = body();
    if (write(fds[1], text.data(), text.size()) != static_cast<ssize_t>(text.size())) _exit(91);
    _exit(0);
  }
  close(fds[1]);
  ChildResult result;
  char buffer[4096];
  for (ssize_t n; (n = read(fds[0], buffer, sizeof(buffer))) > 0;) result.text.append(buffer, n);
  close(fds[0]);
  waitpid(pid, &result.status, 0);
  return result;
}

// DecodeBounded as the body of a child: "refused: <why>" or "accepted".
template <typename Message>
std::function<std::string()> BoundedBody(const std::vector<uint8_t>& bytes,
                                         const DecodeLimits& limits = {}) {
  return [bytes, limits] {
    Message out{};
    std::string why;
    return Decode(bytes, &out, &why, limits) ? std::string("accepted") : "refused: " + why;
  };
}

// LCM's own decoder as the body of a child: "returned <n>" or "threw <what>".
template <typename Message>
std::function<std::string()> LcmBody(const std::vector<uint8_t>& bytes) {
  return [bytes] {
    Message out{};
    try {
      return "returned " +
             std::to_string(out.decode(bytes.data(), 0, static_cast<int>(bytes.size())));
    } catch (const std::bad_alloc&) {
      return std::string("threw std::bad_alloc");
    } catch (const std::exception& error) {
      return std::string("threw ") + error.what();
    }
  };
}

// a valid scene decodes to what LCM's own decoder makes of it, field for field (same encoding).
TEST(BoundedDecodeTest, SceneRoundTripMatchesLcm) {
  const std::vector<uint8_t> bytes = Encode(MakeScene());
  scene bounded;
  std::string why;
  ASSERT_TRUE(Decode(bytes, &bounded, &why)) << why;
  scene lcm;
  ASSERT_EQ(lcm.decode(bytes.data(), 0, static_cast<int>(bytes.size())),
            static_cast<int>(bytes.size()));
  EXPECT_EQ(Encode(bounded), Encode(lcm));
  EXPECT_EQ(Encode(bounded), bytes);
  ASSERT_EQ(bounded.instances.size(), 3u);
  EXPECT_EQ(bounded.instances[1].mask_visib_rle, "o04d0N2O1O00001N2N3L");
  EXPECT_EQ(bounded.instances[2].mask_visib_rle, "");
  EXPECT_EQ(bounded.instances[2].class_name, "bolt");
  EXPECT_EQ(bounded.color.data, MakeScene().color.data);
  EXPECT_EQ(bounded.depth.encoding, image::ENCODING_PNG);
}

// a valid labels message decodes to what LCM's own decoder makes of it.
TEST(BoundedDecodeTest, LabelsRoundTripMatchesLcm) {
  const std::vector<uint8_t> bytes = Encode(LabelsOf(MakeScene()));
  labels bounded;
  std::string why;
  ASSERT_TRUE(Decode(bytes, &bounded, &why)) << why;
  labels lcm;
  ASSERT_EQ(lcm.decode(bytes.data(), 0, static_cast<int>(bytes.size())),
            static_cast<int>(bytes.size()));
  EXPECT_EQ(Encode(bounded), Encode(lcm));
  EXPECT_EQ(Encode(bounded), bytes);
  EXPECT_EQ(bounded.num_instances, 3);
}

// RAW, PNG and JPEG images of every pixel format they hold decode to what LCM makes of them.
TEST(BoundedDecodeTest, ImageRoundTripsMatchLcm) {
  const std::vector<image> images = {
      MakeRawImage(image::PIXEL_GRAY8, 1),
      MakeRawImage(image::PIXEL_INSTANCE16, 2),
      MakeEncodedImage(Pattern(CV_8UC3), image::PIXEL_RGB8, ".png"),
      MakeEncodedImage(Pattern(CV_16UC1), image::PIXEL_DEPTH16, ".png"),
      MakeEncodedImage(Pattern(CV_8UC3), image::PIXEL_RGB8, ".jpg"),
      MakeEncodedImage(Pattern(CV_8UC1), image::PIXEL_GRAY8, ".jpg")};
  for (const image& original : images) {
    const std::vector<uint8_t> bytes = Encode(original);
    image bounded;
    std::string why;
    ASSERT_TRUE(Decode(bytes, &bounded, &why)) << why;
    image lcm;
    ASSERT_EQ(lcm.decode(bytes.data(), 0, static_cast<int>(bytes.size())),
              static_cast<int>(bytes.size()));
    EXPECT_EQ(Encode(bounded), Encode(lcm));
    EXPECT_TRUE(CheckEncodedImageDims(bounded, &why)) << why;
  }
}

// the other message types (strings, a counted array) decode to what LCM makes of them.
TEST(BoundedDecodeTest, OtherTypesRoundTripMatchLcm) {
  status s{};
  s.header.seq = 5;
  s.process = "stackgen";
  s.name = "stackgen@host/2";
  s.scenes = 7;
  s.rate_hz = 2.5;
  config_text c{};
  c.path = "config/default.pbtxt";
  c.pbtxt = "seed: 1\ncamera { width: 640 }\n";
  credit k{};
  k.consumer = "stackgen-coco@host:/data/out";
  k.window = 16;
  k.last_received_seq = -1;
  resend_request r{};
  r.consumer = "stackgen-coco@host:/data/out";
  r.seqs = {3, 4, 9};
  r.num_seqs = 3;
  header h{};
  h.seq = 12;
  std::string why;
  const auto check = [&why](const auto& original) {
    using Message = std::decay_t<decltype(original)>;
    const std::vector<uint8_t> bytes = Encode(original);
    Message bounded{};
    EXPECT_TRUE(Decode(bytes, &bounded, &why)) << Message::getTypeName() << ": " << why;
    EXPECT_EQ(Encode(bounded), bytes) << Message::getTypeName();
  };
  check(s);
  check(c);
  check(k);
  check(r);
  check(h);
  check(MakeInstance(4, "connector", "abc", "de"));
  model m{};
  m.class_id = 2;
  m.class_name = "dowel_pin";
  m.vertices_mm = {{0.f, 0.f, 0.f}, {1.f, 0.f, 0.f}, {0.f, 1.f, 0.f}};
  m.normals = {{0.f, 0.f, 1.f}, {0.f, 0.f, 1.f}, {0.f, 0.f, 1.f}};
  m.num_vertices = 3;
  m.triangles = {{0, 1, 2}};
  m.num_triangles = 1;
  m.diameter_mm = 1.5;
  m.discrete_symmetries = {std::vector<double>(16, 0.5)};
  m.num_discrete_symmetries = 1;
  m.continuous_axes = {{1.0, 0.0, 0.0}};
  m.continuous_offsets_mm = {{0.0, 2.0, 0.0}};
  m.num_continuous_symmetries = 1;
  check(m);
}

// a status message on a scene channel is named as the wrong type, not a decode failure.
TEST(BoundedDecodeTest, StatusWhereSceneExpectedIsWrongType) {
  status s{};
  s.process = "stackgen";
  const std::vector<uint8_t> bytes = Encode(s);
  scene out;
  std::string why;
  EXPECT_FALSE(Decode(bytes, &out, &why));
  EXPECT_NE(why.find("wrong type"), std::string::npos) << why;
  EXPECT_NE(why.find("is stackgen.status, not stackgen.scene"), std::string::npos) << why;
  // a fingerprint of no stackgen type
  std::vector<uint8_t> unknown = Encode(MakeScene());
  unknown[0] ^= 0x40;
  EXPECT_FALSE(Decode(unknown, &out, &why));
  EXPECT_NE(why.find(" is not stackgen.scene"), std::string::npos) << why;
}

// a message above max_message_bytes is refused before it is decoded.
TEST(BoundedDecodeTest, OversizedMessageRefused) {
  const std::vector<uint8_t> bytes = Encode(MakeScene());
  DecodeLimits limits;
  limits.max_message_bytes = bytes.size() - 1;
  scene out;
  std::string why;
  EXPECT_FALSE(Decode(bytes, &out, &why, limits));
  EXPECT_NE(why.find("exceeds max_message_bytes"), std::string::npos) << why;
  limits.max_message_bytes = bytes.size();
  EXPECT_TRUE(Decode(bytes, &out, &why, limits)) << why;
}

// every truncation of a valid scene is refused (no crash) and leaves the output untouched; so
// is a byte left over at the end.
TEST(BoundedDecodeTest, EveryTruncationRefused) {
  const std::vector<uint8_t> bytes = Encode(MakeScene());
  scene out{};
  out.header.seq = -99;
  std::string why;
  for (size_t length = 0; length < bytes.size(); ++length) {
    const std::vector<uint8_t> cut(bytes.begin(), bytes.begin() + length);
    why.clear();
    ASSERT_FALSE(Decode(cut, &out, &why)) << length;
    ASSERT_FALSE(why.empty()) << length;
    ASSERT_EQ(out.header.seq, -99) << length;
  }
  std::vector<uint8_t> longer = bytes;
  longer.push_back(0);
  EXPECT_FALSE(Decode(longer, &out, &why));
  EXPECT_NE(why.find("1 bytes left over"), std::string::npos) << why;
}

// a corrupt count, size or string length is refused with a reason naming the field, and
// without allocating for it: each case runs in a child that may grow by only 1 GiB.
TEST(BoundedDecodeTest, CorruptCountsRefusedWithinAddressLimit) {
  const scene s = MakeScene();
  const std::vector<uint8_t> valid = Encode(s);
  const size_t color = ColorOffset(s);
  struct Case {
    std::string name;
    std::function<void(std::vector<uint8_t>*)> corrupt;
    std::string reason;
  };
  const std::vector<Case> cases = {
      {"num_instances INT32_MAX", [&](auto* b) { PutInt32(b, NumInstancesOffset(s), INT32_MAX); },
       "num_instances 2147483647 needs at least"},
      {"num_instances -1", [&](auto* b) { PutInt32(b, NumInstancesOffset(s), -1); },
       "num_instances -1 is negative"},
      {"num_instances INT32_MIN", [&](auto* b) { PutInt32(b, NumInstancesOffset(s), INT32_MIN); },
       "num_instances -2147483648 is negative"},
      {"num_suction_grasps INT32_MAX",
       [&](auto* b) { PutInt32(b, NumSuctionGraspsOffset(s), INT32_MAX); },
       "num_suction_grasps 2147483647 needs at least"},
      {"num_suction_grasps -3", [&](auto* b) { PutInt32(b, NumSuctionGraspsOffset(s), -3); },
       "num_suction_grasps -3 is negative"},
      {"num_jaw_grasps INT32_MAX", [&](auto* b) { PutInt32(b, NumJawGraspsOffset(s), INT32_MAX); },
       "num_jaw_grasps 2147483647 needs at least"},
      {"color.size INT32_MAX", [&](auto* b) { PutInt32(b, color + kImageSize, INT32_MAX); },
       "color.size 2147483647 needs 2147483647 bytes"},
      {"color.size -1", [&](auto* b) { PutInt32(b, color + kImageSize, -1); },
       "color.size -1 is negative"},
      {"color.size one short", [&](auto* b) { PutInt32(b, color + kImageSize, 2303); },
       "color.size 2303 != width*height*3 (2304) for a RAW RGB8 image"},
      {"color 70000x70000",
       [&](auto* b) {
         PutInt32(b, color + kImageWidth, 70000);
         PutInt32(b, color + kImageHeight, 70000);
       },
       "color image 70000x70000 exceeds max_image_pixels"},
      // 65536 * 65536 is 0 in 32-bit arithmetic
      {"color 65536x65536",
       [&](auto* b) {
         PutInt32(b, color + kImageWidth, 65536);
         PutInt32(b, color + kImageHeight, 65536);
       },
       "color image 65536x65536 exceeds max_image_pixels"},
      {"color width -32", [&](auto* b) { PutInt32(b, color + kImageWidth, -32); },
       "color image -32x24 has a negative side"},
      {"color.pixel_format 9", [&](auto* b) { (*b)[color + kImagePixelFormat] = 9; },
       "color.pixel_format 9 is not a known pixel format"},
      {"class_name length INT32_MIN",
       [&](auto* b) { PutInt32(b, FirstClassNameLengthOffset(s), INT32_MIN); },
       "instances[0] string 1 of 3 (byte 8) has length -2147483648"},
      {"class_name length 0", [&](auto* b) { PutInt32(b, FirstClassNameLengthOffset(s), 0); },
       "instances[0] string 1 of 3 (byte 8) has length 0"},
      {"class_name length INT32_MAX",
       [&](auto* b) { PutInt32(b, FirstClassNameLengthOffset(s), INT32_MAX); },
       "instances[0] string 1 of 3 (byte 8) has length 2147483647"},
  };
  for (const Case& c : cases) {
    std::vector<uint8_t> bytes = valid;
    c.corrupt(&bytes);
    const ChildResult result = RunWithAddressLimit(BoundedBody<scene>(bytes));
    EXPECT_TRUE(result.ExitedZero()) << c.name << ": " << result.Describe();
    EXPECT_EQ(result.text.rfind("refused: ", 0), 0u) << c.name << ": " << result.Describe();
    EXPECT_NE(result.text.find(c.reason), std::string::npos) << c.name << ": " << result.text;
  }
  // the same counts in labels, image, status and resend_request messages
  std::vector<uint8_t> labels_bytes = Encode(LabelsOf(s));
  PutInt32(&labels_bytes, NumInstancesOffset(s), INT32_MAX);
  ChildResult result = RunWithAddressLimit(BoundedBody<labels>(labels_bytes));
  EXPECT_NE(result.text.find("refused: num_instances 2147483647"), std::string::npos)
      << result.Describe();
  std::vector<uint8_t> image_bytes = Encode(s.color);
  PutInt32(&image_bytes, 8 + kImageSize, INT32_MAX);
  result = RunWithAddressLimit(BoundedBody<image>(image_bytes));
  EXPECT_NE(result.text.find("refused: image.size 2147483647"), std::string::npos)
      << result.Describe();
  status st{};
  st.process = "stackgen";
  std::vector<uint8_t> status_bytes = Encode(st);
  // the length of status.process: after the header, next_seq and scenes_held
  PutInt32(&status_bytes, 8 + static_cast<size_t>(st.header._getEncodedSizeNoHash()) + 16,
           INT32_MIN);
  result = RunWithAddressLimit(BoundedBody<status>(status_bytes));
  EXPECT_NE(result.text.find("refused: stackgen.status string 1"), std::string::npos)
      << result.Describe();
  resend_request r{};
  r.consumer = "c";
  std::vector<uint8_t> resend_bytes = Encode(r);
  PutInt32(&resend_bytes, resend_bytes.size() - 4, INT32_MAX);
  result = RunWithAddressLimit(BoundedBody<resend_request>(resend_bytes));
  EXPECT_NE(result.text.find("refused: num_seqs 2147483647 needs at least"), std::string::npos)
      << result.Describe();
  // a model whose vertex count claims 2^31 - 1 rows (num_vertices follows the header, class_id
  // and two strings of one char)
  model m{};
  m.class_name = "c";
  m.mesh = "m";
  std::vector<uint8_t> model_bytes = Encode(m);
  PutInt32(&model_bytes, 8 + static_cast<size_t>(m.header._getEncodedSizeNoHash()) + 4 + 6 + 6,
           INT32_MAX);
  result = RunWithAddressLimit(BoundedBody<model>(model_bytes));
  EXPECT_NE(result.text.find("refused: vertices_mm rows 2147483647 needs at least"),
            std::string::npos)
      << result.Describe();
}

// the guard matters: LCM's own decoder, given the same corrupt bytes under the same limit,
// tries to allocate gigabytes (or crashes) instead of returning an error.
TEST(BoundedDecodeTest, LcmDecoderAllocatesForCorruptCounts) {
  if (kSanitized) GTEST_SKIP() << "sanitizers reserve more address space than the limit";
  const scene s = MakeScene();
  const std::vector<uint8_t> valid = Encode(s);
  std::vector<uint8_t> many_instances = valid;
  PutInt32(&many_instances, NumInstancesOffset(s), INT32_MAX);
  std::vector<uint8_t> huge_color = valid;
  PutInt32(&huge_color, ColorOffset(s) + kImageSize, INT32_MAX);
  for (const std::vector<uint8_t>& bytes : {many_instances, huge_color}) {
    const ChildResult lcm = RunWithAddressLimit(LcmBody<scene>(bytes));
    EXPECT_EQ(lcm.text, "threw std::bad_alloc") << lcm.Describe();
    const ChildResult bounded = RunWithAddressLimit(BoundedBody<scene>(bytes));
    EXPECT_TRUE(bounded.ExitedZero()) << bounded.Describe();
    EXPECT_EQ(bounded.text.rfind("refused: ", 0), 0u) << bounded.Describe();
  }
  // a string length of INT32_MIN: LCM's decoder reads 2 GiB past the message (or throws)
  status st{};
  st.process = "stackgen";
  std::vector<uint8_t> status_bytes = Encode(st);
  // the length of status.process: after the header, next_seq and scenes_held
  PutInt32(&status_bytes, 8 + static_cast<size_t>(st.header._getEncodedSizeNoHash()) + 16,
           INT32_MIN);
  const ChildResult lcm = RunWithAddressLimit(LcmBody<status>(status_bytes));
  EXPECT_FALSE(lcm.ExitedZero() && lcm.text.rfind("returned ", 0) == 0) << lcm.Describe();
}

// 2000 seeded mutations of a valid scene (byte flips, truncations, planted counts) never crash
// or allocate beyond the limit, and every message accepted re-encodes to exactly its bytes.
TEST(BoundedDecodeTest, SeededFuzzNeverCrashesAndAcceptedReencodes) {
  const std::vector<uint8_t> valid = Encode(MakeScene());
  const ChildResult result = RunWithAddressLimit([&valid]() -> std::string {
    std::mt19937_64 engine(20240611);
    const int32_t planted[] = {0, 1, -1, 255, 65536, INT32_MAX, INT32_MIN, 1 << 20};
    int accepted = 0;
    int refused = 0;
    for (int iteration = 0; iteration < 2000; ++iteration) {
      std::vector<uint8_t> bytes = valid;
      const auto at = [&] { return static_cast<size_t>(engine() % bytes.size()); };
      const int kind = static_cast<int>(engine() % 4);
      // flips of 1 to 8 bytes, a count planted at a random offset, a truncation, or all three
      if (kind == 0 || kind == 3) {
        for (int n = 1 + static_cast<int>(engine() % 8); n > 0; --n) {
          bytes[at()] ^= static_cast<uint8_t>(1 + engine() % 255);
        }
      }
      if (kind == 1 || kind == 3) {
        const size_t offset = at() % (bytes.size() - 4);
        PutInt32(&bytes, offset, planted[engine() % 8]);
      }
      if (kind == 2 || kind == 3) bytes.resize(at());
      scene out;
      std::string why;
      if (!Decode(bytes, &out, &why)) {
        if (why.empty()) return "no reason at iteration " + std::to_string(iteration);
        ++refused;
        continue;
      }
      ++accepted;
      if (Encode(out) != bytes)
        return "re-encoding differs at iteration " + std::to_string(iteration);
      for (const image* m : {&out.color, &out.depth, &out.instance_map})
        CheckEncodedImageDims(*m, &why);
    }
    return "ok accepted " + std::to_string(accepted) + " refused " + std::to_string(refused);
  });
  ASSERT_TRUE(result.ExitedZero()) << result.Describe();
  ASSERT_EQ(result.text.rfind("ok ", 0), 0u) << result.Describe();
  int accepted = 0;
  int refused = 0;
  ASSERT_EQ(std::sscanf(result.text.c_str(), "ok accepted %d refused %d", &accepted, &refused), 2);
  // both outcomes occur, so the fuzz exercised the accepting path too
  EXPECT_GT(accepted, 100) << result.text;
  EXPECT_GT(refused, 500) << result.text;
}

// real PNG and JPEG files of the declared size and format pass; RAW passes when sized right.
TEST(BoundedDecodeTest, CheckEncodedImageDimsAcceptsRealFiles) {
  std::string why;
  for (const image& m :
       {MakeEncodedImage(Pattern(CV_8UC3), image::PIXEL_RGB8, ".png"),
        MakeEncodedImage(Pattern(CV_8UC1), image::PIXEL_GRAY8, ".png"),
        MakeEncodedImage(Pattern(CV_16UC1), image::PIXEL_DEPTH16, ".png"),
        MakeEncodedImage(Pattern(CV_16UC1), image::PIXEL_INSTANCE16, ".png"),
        MakeEncodedImage(Pattern(CV_8UC3), image::PIXEL_RGB8, ".jpg"),
        MakeEncodedImage(Pattern(CV_8UC1), image::PIXEL_GRAY8, ".jpg"),
        MakeRawImage(image::PIXEL_RGB8, 3), MakeRawImage(image::PIXEL_DEPTH16, 2)}) {
    EXPECT_TRUE(CheckEncodedImageDims(m, &why)) << why;
  }
  image progressive{};
  progressive.width = kWidth;
  progressive.height = kHeight;
  progressive.pixel_format = image::PIXEL_RGB8;
  progressive.encoding = image::ENCODING_JPEG;
  ASSERT_TRUE(
      cv::imencode(".jpg", Pattern(CV_8UC3), progressive.data, {cv::IMWRITE_JPEG_PROGRESSIVE, 1}));
  progressive.size = static_cast<int32_t>(progressive.data.size());
  EXPECT_TRUE(CheckEncodedImageDims(progressive, &why)) << why;
}

// a small PNG or JPEG whose header claims 60000 x 60000 pixels (a decompression bomb), or a
// format other than the declared one, is refused before any decoder sees it.
TEST(BoundedDecodeTest, CheckEncodedImageDimsRefusesMismatches) {
  std::string why;
  image png = MakeEncodedImage(Pattern(CV_8UC3), image::PIXEL_RGB8, ".png");
  // IHDR width and height, big-endian at bytes 16 and 20
  image bomb = png;
  PutInt32(&bomb.data, 16, 60000);
  PutInt32(&bomb.data, 20, 60000);
  EXPECT_FALSE(CheckEncodedImageDims(bomb, &why));
  EXPECT_NE(why.find("PNG header says 60000x60000, the image declares 32x24"), std::string::npos)
      << why;
  // an 8-bit PNG declared as 16-bit depth
  image depth = png;
  depth.pixel_format = image::PIXEL_DEPTH16;
  EXPECT_FALSE(CheckEncodedImageDims(depth, &why));
  EXPECT_NE(why.find("bit depth 8"), std::string::npos) << why;
  // a JPEG whose frame header claims 60000 x 60000
  image jpeg = MakeEncodedImage(Pattern(CV_8UC3), image::PIXEL_RGB8, ".jpg");
  const std::vector<uint8_t>& d = jpeg.data;
  size_t sof = 2;
  while (sof + 4 < d.size() && !(d[sof] == 0xFF && d[sof + 1] >= 0xC0 && d[sof + 1] <= 0xC2)) {
    sof += 2 + ((size_t{d[sof + 2]} << 8) | d[sof + 3]);
  }
  ASSERT_LT(sof + 9, d.size());
  image jpeg_bomb = jpeg;
  for (const size_t at : {sof + 5, sof + 7}) {
    jpeg_bomb.data[at] = 0xEA;  // 60000 = 0xEA60
    jpeg_bomb.data[at + 1] = 0x60;
  }
  EXPECT_FALSE(CheckEncodedImageDims(jpeg_bomb, &why));
  EXPECT_NE(why.find("JPEG header says 60000x60000"), std::string::npos) << why;
  // PNG data declared as JPEG, and a RAW image one byte short
  image wrong_format = png;
  wrong_format.encoding = image::ENCODING_JPEG;
  EXPECT_FALSE(CheckEncodedImageDims(wrong_format, &why));
  EXPECT_NE(why.find("not a JPEG"), std::string::npos) << why;
  image raw = MakeRawImage(image::PIXEL_RGB8, 3);
  raw.data.pop_back();
  raw.size -= 1;
  EXPECT_FALSE(CheckEncodedImageDims(raw, &why));
  EXPECT_NE(why.find("size 2303 != width*height*3 (2304)"), std::string::npos) << why;
}

// the fields of each types/*.lcm struct: (type, variable-length array?) pairs.
struct LcmField {
  std::string type;
  int count = 1;  // product of the fixed array sizes
  bool variable = false;
};
std::map<std::string, std::vector<LcmField>> ReadLcmTypes() {
  std::map<std::string, std::vector<LcmField>> types;
  const std::regex comment("//[^\n]*");
  const std::regex structure(R"(struct\s+(\w+)\s*\{([^}]*)\})");
  const std::regex field(R"(^\s*([\w.]+)\s+\w+\s*((?:\[[^\]]*\]\s*)*)$)");
  const std::regex dimension(R"(\[\s*([^\]\s]*)\s*\])");
  for (const auto& entry :
       std::filesystem::directory_iterator(std::string(STACKGEN_SOURCE_DIR) + "/types")) {
    if (entry.path().extension() != ".lcm") continue;
    std::ifstream file(entry.path());
    std::stringstream text;
    text << file.rdbuf();
    const std::string source = std::regex_replace(text.str(), comment, "");
    for (std::sregex_iterator s(source.begin(), source.end(), structure), end; s != end; ++s) {
      std::vector<LcmField>& fields = types[(*s)[1]];
      std::stringstream body((*s)[2].str());
      for (std::string statement; std::getline(body, statement, ';');) {
        std::smatch match;
        if (statement.find("const ") != std::string::npos ||
            !std::regex_match(statement, match, field)) {
          continue;
        }
        LcmField f;
        f.type = match[1];
        if (f.type.rfind("stackgen.", 0) == 0) f.type = f.type.substr(9);
        const std::string dims = match[2];
        for (std::sregex_iterator d(dims.begin(), dims.end(), dimension); d != end; ++d) {
          const std::string size = (*d)[1];
          if (!size.empty() && std::isdigit(static_cast<unsigned char>(size[0]))) {
            f.count *= std::stoi(size);
          } else {
            f.variable = true;
          }
        }
        fields.push_back(f);
      }
    }
  }
  return types;
}

// a type in types/ that has a variable-length array, or holds one that does, has its own
// specialisation: the generic version would let its generated decoder size the array.
TEST(BoundedDecodeTest, TypesWithArraysHaveSpecialisations) {
  const auto types = ReadLcmTypes();
  ASSERT_GE(types.size(), 9u);
  ASSERT_TRUE(types.count("scene") && types.count("image"));
  std::function<bool(const std::string&)> has_array = [&](const std::string& name) {
    const auto it = types.find(name);
    if (it == types.end()) return false;
    for (const LcmField& f : it->second) {
      if (f.variable || has_array(f.type)) return true;
    }
    return false;
  };
  for (const auto& [name, fields] : types) {
    if (has_array(name)) {
      EXPECT_TRUE(kSpecialised.count(name))
          << "stackgen." << name << " has a variable-length array but no DecodeBounded "
          << "specialisation in contract/bounded_decode.h";
    }
  }
}

// the string layout found from an empty message has one entry per string of the type, as
// types/*.lcm declares them (nested structs included).
TEST(BoundedDecodeTest, StringLayoutFindsEveryString) {
  const auto types = ReadLcmTypes();
  std::function<int(const std::string&)> strings = [&](const std::string& name) {
    if (name == "string") return 1;
    const auto it = types.find(name);
    int total = 0;
    if (it != types.end()) {
      for (const LcmField& f : it->second) total += f.count * strings(f.type);
    }
    return total;
  };
  const std::map<std::string, const internal::StringLayout*> layouts = {
      {"header", &internal::StringLayoutOf<header>()},
      {"camera_info", &internal::StringLayoutOf<camera_info>()},
      {"instance", &internal::StringLayoutOf<instance>()},
      {"status", &internal::StringLayoutOf<status>()},
      {"config_text", &internal::StringLayoutOf<config_text>()},
      {"credit", &internal::StringLayoutOf<credit>()}};
  for (const auto& [name, layout] : layouts) {
    EXPECT_TRUE(layout->valid) << name;
    EXPECT_EQ(static_cast<int>(layout->length_offsets.size()), strings(name)) << name;
  }
  EXPECT_EQ(strings("instance"), 3);
}

}  // namespace
}  // namespace stackgen
