// stackgen._native: the C++ half of the Python package `stackgen` (pybind11). It binds the scene
// stream (session/delivery.h's credits and resend, bounded decoding, checks and image decoding all
// run in C++, outside the GIL), the scene with its arrays, RLE mask decoding, a log appender and a
// status monitor. The Python modules of the package (consumers/feed/stackgen/) wrap it.

#include <Python.h>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <array>
#include <cerrno>
#include <chrono>
#include <cstring>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <stackgen/scene.hpp>

#include "bus/bus.h"
#include "bus/log.h"
#include "consumers/feed/learner_publisher.h"
#include "consumers/feed/scene_data.h"
#include "consumers/feed/scene_stream.h"
#include "consumers/feed/status_monitor.h"

namespace py = pybind11;

namespace stackgen::feed {
namespace {

PyObject* stream_error_type = nullptr;
PyObject* stream_timeout_type = nullptr;

// a numpy array over a cv::Mat's pixels without a copy: the array keeps the matrix (and so its
// data, or the scene whose RAW bytes it points into) alive
py::array MatToArray(const cv::Mat& mat, const py::object& owner) {
  std::vector<py::ssize_t> shape = {mat.rows, mat.cols};
  std::vector<py::ssize_t> strides = {static_cast<py::ssize_t>(mat.step[0]),
                                      static_cast<py::ssize_t>(mat.elemSize())};
  if (mat.channels() > 1) {
    shape.push_back(mat.channels());
    strides.push_back(static_cast<py::ssize_t>(mat.elemSize1()));
  }
  auto* kept = new cv::Mat(mat);
  py::capsule base(kept, [](void* pointer) { delete static_cast<cv::Mat*>(pointer); });
  // the owner too: a RAW image's matrix points into the scene message
  py::tuple bases = py::make_tuple(base, owner);
  py::array array;
  if (mat.depth() == CV_16U) {
    array = py::array_t<uint16_t>(shape, strides, reinterpret_cast<uint16_t*>(mat.data), bases);
  } else {
    array = py::array_t<uint8_t>(shape, strides, mat.data, bases);
  }
  // the scene's images are shared, not to be written into
  array.attr("setflags")(py::arg("write") = false);
  return array;
}

// a (N, rows, cols) float64 array filled by `fill(k, out)`
template <typename Fill>
py::array_t<double> PerInstance(const scene& message, std::vector<py::ssize_t> shape, Fill fill) {
  shape.insert(shape.begin(), static_cast<py::ssize_t>(message.instances.size()));
  py::array_t<double> array(shape);
  double* out = array.mutable_data();
  size_t stride = 1;
  for (size_t d = 1; d < shape.size(); ++d) stride *= static_cast<size_t>(shape[d]);
  for (size_t k = 0; k < message.instances.size(); ++k)
    fill(message.instances[k], out + k * stride);
  return array;
}

// the 4x4 homogeneous matrix of a pose
void PoseMatrix(const pose& p, double* out) {
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) out[r * 4 + c] = p.rotation[r * 3 + c];
    out[r * 4 + 3] = p.translation_mm[r];
  }
  out[12] = out[13] = out[14] = 0;
  out[15] = 1;
}

template <typename T, typename Get>
py::array_t<T> InstanceField(const scene& message, Get get) {
  py::array_t<T> array(static_cast<py::ssize_t>(message.instances.size()));
  T* out = array.mutable_data();
  for (size_t k = 0; k < message.instances.size(); ++k) out[k] = get(message.instances[k]);
  return array;
}

py::array_t<int32_t> Boxes(const scene& message, bool visible) {
  py::array_t<int32_t> array({static_cast<py::ssize_t>(message.instances.size()), py::ssize_t{4}});
  int32_t* out = array.mutable_data();
  for (size_t k = 0; k < message.instances.size(); ++k) {
    const int32_t* box = visible ? message.instances[k].bbox_visib : message.instances[k].bbox_obj;
    std::memcpy(out + 4 * k, box, 4 * sizeof(int32_t));
  }
  return array;
}

// the masks of the instances at `indices` (all when none), (M, height, width) uint8 0/1
py::array_t<uint8_t> Masks(const FeedScene& scene_data,
                           const std::optional<std::vector<int>>& indices, bool visible) {
  const scene& message = scene_data.message();
  std::vector<int> chosen;
  if (indices) {
    chosen = *indices;
  } else {
    for (size_t k = 0; k < message.instances.size(); ++k) chosen.push_back(static_cast<int>(k));
  }
  for (const int k : chosen) {
    if (k < 0 || k >= static_cast<int>(message.instances.size())) {
      throw py::index_error("instance index " + std::to_string(k) + " is outside 0.." +
                            std::to_string(static_cast<int>(message.instances.size()) - 1));
    }
  }
  const int height = message.camera.height, width = message.camera.width;
  py::array_t<uint8_t> array(
      {static_cast<py::ssize_t>(chosen.size()), py::ssize_t{height}, py::ssize_t{width}});
  uint8_t* out = array.mutable_data();
  {
    py::gil_scoped_release release;
    std::memset(out, 0, chosen.size() * static_cast<size_t>(height) * width);
    for (size_t m = 0; m < chosen.size(); ++m) {
      const instance& object = message.instances[static_cast<size_t>(chosen[m])];
      DecodeRleInto(visible ? object.mask_visib_rle : object.mask_obj_rle, height, width,
                    out + m * static_cast<size_t>(height) * width);
    }
  }
  return array;
}

// each instance's mask within its box (bbox_obj for the full masks, bbox_visib for the visible
// ones): a list of (h, w) uint8 0/1 arrays
py::list BoxedMasks(const FeedScene& scene_data, const std::vector<int>& indices, bool visible) {
  const scene& message = scene_data.message();
  const int height = message.camera.height, width = message.camera.width;
  py::list masks;
  for (const int k : indices) {
    if (k < 0 || k >= static_cast<int>(message.instances.size())) {
      throw py::index_error("instance index " + std::to_string(k) + " is outside 0.." +
                            std::to_string(static_cast<int>(message.instances.size()) - 1));
    }
    const instance& object = message.instances[static_cast<size_t>(k)];
    const int32_t* box = visible ? object.bbox_visib : object.bbox_obj;
    py::array_t<uint8_t> mask({py::ssize_t{box[3]}, py::ssize_t{box[2]}});
    uint8_t* out = mask.mutable_data();
    {
      py::gil_scoped_release release;
      std::memset(out, 0, static_cast<size_t>(box[2]) * box[3]);
      DecodeRleWindow(visible ? object.mask_visib_rle : object.mask_obj_rle, height, width, box[0],
                      box[1], box[2], box[3], out);
    }
    masks.append(mask);
  }
  return masks;
}

py::dict CountersDict(const StreamCounters& c) {
  py::dict d;
  d["received"] = c.received;
  d["handed"] = c.handed;
  d["duplicates"] = c.duplicates;
  d["lost"] = c.lost;
  d["reasked"] = c.reasked;
  d["bad_messages"] = c.bad_messages;
  d["dropped_behind"] = c.dropped_behind;
  d["fault_dropped"] = c.fault_dropped;
  d["refused_unsigned"] = c.refused_unsigned;
  d["refused_forged"] = c.refused_forged;
  d["refused_replayed"] = c.refused_replayed;
  d["refused_relayed"] = c.refused_relayed;
  d["queued"] = c.queued;
  return d;
}

py::dict StatusDict(const status& s) {
  py::dict d;
  d["process"] = s.process;
  d["name"] = s.name;
  d["generator_id"] = s.header.generator_id;
  d["next_seq"] = s.next_seq;
  d["scenes_held"] = s.scenes_held;
  d["utime"] = s.header.utime;
  d["scenes"] = s.scenes;
  d["rate_hz"] = s.rate_hz;
  d["received"] = s.received;
  d["lost"] = s.lost;
  d["resent"] = s.resent;
  d["regenerated"] = s.regenerated;
  d["reliable_consumers"] = s.reliable_consumers;
  d["held_back_s"] = s.held_back_s;
  d["run_state"] = s.run_state;
  return d;
}

}  // namespace
}  // namespace stackgen::feed

namespace {

using SceneClass =
    py::class_<stackgen::feed::FeedScene, std::shared_ptr<stackgen::feed::FeedScene>>;
void BindSceneImages(SceneClass& scene);
void BindSceneInstances(SceneClass& scene);
void BindSceneMasks(SceneClass& scene);
void BindSceneGrasps(SceneClass& scene);

// stackgen.Scene: a checked scene, its arrays without copies, masks decoded on demand
void BindScene(py::module_& m) {
  using namespace stackgen;
  using namespace stackgen::feed;
  SceneClass scene(m, "Scene");
  BindSceneImages(scene);
  BindSceneInstances(scene);
  BindSceneMasks(scene);
  BindSceneGrasps(scene);
}

// the header, camera and images of a scene
void BindSceneImages(SceneClass& scene) {
  using namespace stackgen;
  using namespace stackgen::feed;
  scene
      .def_property_readonly("generator_id",
                             [](const FeedScene& s) { return s.message().header.generator_id; })
      .def_property_readonly("seq", [](const FeedScene& s) { return s.message().header.seq; })
      .def_property_readonly("seed", [](const FeedScene& s) { return s.message().header.seed; })
      .def_property_readonly("utime", [](const FeedScene& s) { return s.message().header.utime; })
      .def_readonly("occurrence", &FeedScene::occurrence)
      .def_property_readonly("width", [](const FeedScene& s) { return s.message().camera.width; })
      .def_property_readonly("height", [](const FeedScene& s) { return s.message().camera.height; })
      .def_property_readonly("K",
                             [](const FeedScene& s) {
                               const camera_info& c = s.message().camera;
                               py::array_t<double> k({3, 3});
                               double* out = k.mutable_data();
                               const double values[9] = {c.fx, 0, c.cx, 0, c.fy, c.cy, 0, 0, 1};
                               std::memcpy(out, values, sizeof(values));
                               return k;
                             })
      .def_property_readonly("world_from_camera",
                             [](const FeedScene& s) {
                               py::array_t<double> matrix({4, 4});
                               PoseMatrix(s.message().camera.world_from_camera,
                                          matrix.mutable_data());
                               return matrix;
                             })
      .def_property_readonly("depth_scale_mm",
                             [](const FeedScene& s) { return s.message().camera.depth_scale_mm; })
      .def_property_readonly(
          "is_gray",
          [](const FeedScene& s) { return s.message().color.pixel_format == image::PIXEL_GRAY8; })
      .def_property_readonly("has_depth", &FeedScene::has_depth)
      .def_property_readonly("has_depth_sensor", &FeedScene::has_depth_sensor)
      .def_property_readonly("depth_sensor",
                             [](py::object self) {
                               FeedScene& s = self.cast<FeedScene&>();
                               cv::Mat mat;
                               {
                                 py::gil_scoped_release release;
                                 mat = s.DepthSensor();
                               }
                               return MatToArray(mat, self);
                             })
      .def_property_readonly("color",
                             [](py::object self) {
                               FeedScene& s = self.cast<FeedScene&>();
                               cv::Mat mat;
                               {
                                 py::gil_scoped_release release;
                                 mat = s.Color();
                               }
                               return MatToArray(mat, self);
                             })
      .def_property_readonly("depth",
                             [](py::object self) {
                               FeedScene& s = self.cast<FeedScene&>();
                               cv::Mat mat;
                               {
                                 py::gil_scoped_release release;
                                 mat = s.Depth();
                               }
                               return MatToArray(mat, self);
                             })
      .def_property_readonly("instance_map", [](py::object self) {
        FeedScene& s = self.cast<FeedScene&>();
        cv::Mat mat;
        {
          py::gil_scoped_release release;
          mat = s.InstanceMap();
        }
        return MatToArray(mat, self);
      });
}

// the instances' labels, one array per field
void BindSceneInstances(SceneClass& scene) {
  using namespace stackgen;
  using namespace stackgen::feed;
  scene
      .def_property_readonly("num_instances",
                             [](const FeedScene& s) { return s.message().instances.size(); })
      .def_property_readonly("instance_ids",
                             [](const FeedScene& s) {
                               return InstanceField<int32_t>(
                                   s.message(), [](const instance& i) { return i.instance_id; });
                             })
      .def_property_readonly("class_ids",
                             [](const FeedScene& s) {
                               return InstanceField<int32_t>(
                                   s.message(), [](const instance& i) { return i.class_id; });
                             })
      .def_property_readonly("class_names",
                             [](const FeedScene& s) {
                               std::vector<std::string> names;
                               for (const instance& i : s.message().instances) {
                                 names.push_back(i.class_name);
                               }
                               return names;
                             })
      .def_property_readonly("camera_from_object",
                             [](const FeedScene& s) {
                               return PerInstance(s.message(), {4, 4},
                                                  [](const instance& i, double* out) {
                                                    PoseMatrix(i.camera_from_object, out);
                                                  });
                             })
      .def_property_readonly("world_from_object",
                             [](const FeedScene& s) {
                               return PerInstance(s.message(), {4, 4},
                                                  [](const instance& i, double* out) {
                                                    PoseMatrix(i.world_from_object, out);
                                                  });
                             })
      .def_property_readonly("posture_deg",
                             [](const FeedScene& s) {
                               return PerInstance(
                                   s.message(), {3}, [](const instance& i, double* out) {
                                     std::memcpy(out, i.posture_deg, sizeof(i.posture_deg));
                                   });
                             })
      .def_property_readonly("resting_face",
                             [](const FeedScene& s) {
                               return InstanceField<int32_t>(
                                   s.message(), [](const instance& i) { return i.resting_face; });
                             })
      .def_property_readonly("bbox_obj",
                             [](const FeedScene& s) { return Boxes(s.message(), false); })
      .def_property_readonly("bbox_visib",
                             [](const FeedScene& s) { return Boxes(s.message(), true); })
      .def_property_readonly("px_count_all",
                             [](const FeedScene& s) {
                               return InstanceField<int32_t>(
                                   s.message(), [](const instance& i) { return i.px_count_all; });
                             })
      .def_property_readonly("px_count_visib",
                             [](const FeedScene& s) {
                               return InstanceField<int32_t>(
                                   s.message(), [](const instance& i) { return i.px_count_visib; });
                             })
      .def_property_readonly("visib_fract",
                             [](const FeedScene& s) {
                               return InstanceField<double>(
                                   s.message(), [](const instance& i) { return i.visib_fract; });
                             })
      .def_property_readonly("annotated",
                             [](const FeedScene& s) {
                               return InstanceField<bool>(
                                   s.message(), [](const instance& i) { return i.annotated; });
                             })
      .def_property_readonly("ignored", [](const FeedScene& s) {
        return InstanceField<bool>(s.message(), [](const instance& i) { return i.ignored; });
      });
}

// masks decoded on demand, and the encoded message
void BindSceneMasks(SceneClass& scene) {
  using namespace stackgen;
  using namespace stackgen::feed;
  scene
      .def(
          "masks_visib",
          [](const FeedScene& s, std::optional<std::vector<int>> indices) {
            return Masks(s, indices, true);
          },
          py::arg("indices") = py::none())
      .def(
          "masks_obj",
          [](const FeedScene& s, std::optional<std::vector<int>> indices) {
            return Masks(s, indices, false);
          },
          py::arg("indices") = py::none())
      .def(
          "boxed_masks_obj",
          [](const FeedScene& s, const std::vector<int>& indices) {
            return BoxedMasks(s, indices, false);
          },
          py::arg("indices"),
          "Each listed instance's full mask within its bbox_obj: (h, w) uint8 0/1 arrays.")
      .def(
          "boxed_masks_visib",
          [](const FeedScene& s, const std::vector<int>& indices) {
            return BoxedMasks(s, indices, true);
          },
          py::arg("indices"),
          "Each listed instance's visible mask within its bbox_visib: (h, w) uint8 0/1 arrays.")
      .def("encoded", [](const FeedScene& s) {
        const std::vector<uint8_t> bytes = EncodeMessage(s.message());
        return py::bytes(reinterpret_cast<const char*>(bytes.data()), bytes.size());
      });
}

// stackgen._native.Stream: the C++ stream in a thread of its own
void BindStream(py::module_& m) {
  using namespace stackgen;
  using namespace stackgen::feed;
  py::class_<SceneStream>(m, "Stream")
      .def(py::init([](const std::string& url, const std::string& channel, bool reliable,
                       int32_t window, std::vector<int32_t> generator_ids, int32_t shard_index,
                       int32_t shard_count, int64_t count, int queue, bool repeats,
                       bool decode_instance_map, bool decode_depth, int decode_threads,
                       const std::string& name, double fault_drop, bool publish_status,
                       const std::string& bus_key_file, bool open_bus, bool replay) {
             SceneStreamOptions options;
             options.url = url;
             options.channel = channel;
             options.reliable = reliable;
             options.window = window;
             options.generator_ids = std::move(generator_ids);
             options.shard_index = shard_index;
             options.shard_count = shard_count;
             options.count = count;
             options.queue = queue;
             options.repeats = repeats;
             options.decode_instance_map = decode_instance_map;
             options.decode_depth = decode_depth;
             options.decode_threads = decode_threads;
             options.name = name;
             options.fault_drop = fault_drop;
             options.publish_status = publish_status;
             options.bus_key_file = bus_key_file;
             options.open_bus = open_bus;
             options.replay = replay;
             py::gil_scoped_release release;
             return std::make_unique<SceneStream>(options);
           }),
           py::arg("url"), py::arg("channel"), py::arg("reliable"), py::arg("window"),
           py::arg("generator_ids"), py::arg("shard_index"), py::arg("shard_count"),
           py::arg("count"), py::arg("queue"), py::arg("repeats"), py::arg("decode_instance_map"),
           py::arg("decode_depth"), py::arg("decode_threads"), py::arg("name"),
           py::arg("fault_drop"), py::arg("publish_status"), py::arg("bus_key_file") = "",
           py::arg("open_bus") = false, py::arg("replay") = false)
      .def(
          "next",
          [](SceneStream& stream, std::optional<double> timeout_s) {
            py::gil_scoped_release release;
            // Ctrl-C in the learner stops the wait; the error its signal handler raised
            // (KeyboardInterrupt, or whatever a handler of the caller's raised) is kept and raised
            bool interrupted = false;
            PyObject* error_type = nullptr;
            PyObject* error_value = nullptr;
            PyObject* error_trace = nullptr;
            std::shared_ptr<FeedScene> next = stream.Next(timeout_s ? *timeout_s : -1.0, [&] {
              py::gil_scoped_acquire acquire;
              interrupted = PyErr_CheckSignals() != 0;
              if (interrupted) PyErr_Fetch(&error_type, &error_value, &error_trace);
              return interrupted;
            });
            if (interrupted) {
              py::gil_scoped_acquire acquire;
              if (error_type == nullptr) {
                PyErr_SetNone(PyExc_KeyboardInterrupt);
              } else {
                PyErr_Restore(error_type, error_value, error_trace);
              }
              throw py::error_already_set();
            }
            return next;
          },
          py::arg("timeout_s") = py::none())
      .def("close",
           [](SceneStream& stream) {
             py::gil_scoped_release release;
             stream.Close();
           })
      .def_property_readonly(
          "counters", [](const SceneStream& stream) { return CountersDict(stream.counters()); })
      .def_property_readonly("url", &SceneStream::url)
      .def_property_readonly("name", &SceneStream::name)
      .def_property_readonly("is_log", &SceneStream::is_log);
}

// stackgen._native.LogAppender: LogRecorder's writer
void BindLogAppender(py::module_& m) {
  using namespace stackgen;
  using namespace stackgen::feed;
  py::class_<LogAppender>(m, "LogAppender")
      .def(py::init([](const std::string& path, const std::string& bus_key_file, bool open_bus) {
             try {
               return std::make_unique<LogAppender>(
                   path, open_bus ? "" : ResolveBusKeyFile(bus_key_file));
             } catch (const std::runtime_error& error) {
               throw FeedError(error.what());
             }
           }),
           py::arg("path"), py::arg("bus_key_file") = "", py::arg("open_bus") = false,
           "Appends events to an LCM log, each signed with the bus key (bus_key_file, else "
           "$STACKGEN_BUS_KEY_FILE, else this user's key) so the log replays under that key; "
           "open_bus: unsigned.")
      .def(
          "append",
          [](LogAppender& log, const std::string& channel, const py::bytes& data, int64_t utime) {
            const std::string bytes = data;
            py::gil_scoped_release release;
            try {
              log.AppendBytes(channel, reinterpret_cast<const uint8_t*>(bytes.data()), bytes.size(),
                              utime);
            } catch (const std::runtime_error& error) {
              throw FeedError(error.what());
            }
          },
          py::arg("channel"), py::arg("data"), py::arg("utime"))
      .def_property_readonly("path", &LogAppender::path);
}

// stackgen._native.StatusMonitor
void BindStatusMonitor(py::module_& m) {
  using namespace stackgen;
  using namespace stackgen::feed;
  py::class_<StatusMonitor>(m, "StatusMonitor")
      .def(py::init([](const std::string& url, const std::string& bus_key_file, bool open_bus) {
             py::gil_scoped_release release;
             return std::make_unique<StatusMonitor>(url, bus_key_file, open_bus);
           }),
           py::arg("url"), py::arg("bus_key_file") = "", py::arg("open_bus") = false)
      .def("latest", [](const StatusMonitor& monitor) {
        py::list statuses;
        for (const auto& [name, message] : monitor.Latest()) statuses.append(StatusDict(message));
        return statuses;
      });
}

// stackgen._native.LearnerPublisher
void BindLearnerPublisher(py::module_& m) {
  using namespace stackgen;
  using namespace stackgen::feed;
  py::class_<LearnerPublisher>(m, "LearnerPublisher")
      .def(py::init([](const std::string& url, const std::string& bus_key_file, bool open_bus,
                       const std::string& process, const std::string& name) {
             py::gil_scoped_release release;
             return std::make_unique<LearnerPublisher>(url, bus_key_file, open_bus, process,
                                                       name);
           }),
           py::arg("url"), py::arg("bus_key_file"), py::arg("open_bus"), py::arg("process"),
           py::arg("name"))
      .def(
          "report",
          [](LearnerPublisher& publisher, int64_t steps, int64_t target_steps, double loss,
             int64_t scenes_taken, double scenes_per_second, double reuse) {
            publisher.Report({steps, target_steps, loss, scenes_taken, scenes_per_second, reuse});
          },
          py::arg("steps"), py::arg("target_steps"), py::arg("loss"), py::arg("scenes_taken"),
          py::arg("scenes_per_second"), py::arg("reuse"))
      .def(
          "close",
          [](LearnerPublisher& publisher, bool ended) {
            py::gil_scoped_release release;
            publisher.Close(ended);
          },
          py::arg("ended"));
}

// the module's functions and constants
void BindFunctions(py::module_& m) {
  using namespace stackgen;
  using namespace stackgen::feed;
  m.def(
      "decode_rle",
      [](const std::string& counts, int height, int width) {
        if (height < 0 || width < 0) throw py::value_error("a mask size must be >= 0");
        py::array_t<uint8_t> mask({py::ssize_t{height}, py::ssize_t{width}});
        std::memset(mask.mutable_data(), 0, static_cast<size_t>(height) * width);
        try {
          DecodeRleInto(counts, height, width, mask.mutable_data());
        } catch (const std::runtime_error& error) {
          throw py::value_error(std::string("not a COCO RLE mask of ") + std::to_string(height) +
                                "x" + std::to_string(width) + " pixels: " + error.what());
        }
        return mask;
      },
      py::arg("counts"), py::arg("height"), py::arg("width"),
      "The (height, width) uint8 0/1 mask of a COCO compressed RLE string.");
  m.def("resolve_lcm_url", &ResolveLcmUrl, py::arg("url"),
        "The URL a stream uses: `url` when not empty, else $STACKGEN_LCM_URL, else the default.");
  m.attr("DEFAULT_LCM_URL") = kDefaultLcmUrl;

  // the bus's warnings start with the program's name (glibc's program_invocation_short_name):
  // in Python that is the interpreter's, "python3"; "stackgen" until the program names itself
  static std::string program_name = "stackgen";
  program_invocation_short_name = program_name.data();
  m.def(
      "set_program_name",
      [](const std::string& name) {
        if (name.empty() || name.find('\n') != std::string::npos) {
          throw py::value_error("a program name must be one non-empty line");
        }
        program_name = name;
        program_invocation_short_name = program_name.data();
      },
      py::arg("name"),
      "Names the program in the stream's warnings on stderr (\"NAME: warning: ...\"); default "
      "\"stackgen\".");
}
// a column over `items`: get(item) of each
template <typename T, typename Item, typename Get>
py::array_t<T> Column(const std::vector<Item>& items, Get get) {
  py::array_t<T> array(static_cast<py::ssize_t>(items.size()));
  T* out = array.mutable_data();
  for (size_t k = 0; k < items.size(); ++k) out[k] = static_cast<T>(get(items[k]));
  return array;
}

// an (N, n) array over `items`: the n values get(item) points at, of each
template <typename T, int n, typename Item, typename Get>
py::array_t<T> Rows(const std::vector<Item>& items, Get get) {
  py::array_t<T> array({static_cast<py::ssize_t>(items.size()), py::ssize_t{n}});
  T* out = array.mutable_data();
  for (size_t k = 0; k < items.size(); ++k) {
    for (int c = 0; c < n; ++c) out[k * n + c] = static_cast<T>(get(items[k])[c]);
  }
  return array;
}

// what both kinds of grasps have: the instance, rank, pixel, approach and proof
template <typename Grasp>
py::dict GraspColumns(const std::vector<Grasp>& g) {
  py::dict out;
  out["instance_id"] = Column<int32_t>(g, [](const Grasp& x) { return x.instance_id; });
  out["rank"] = Column<int32_t>(g, [](const Grasp& x) { return x.rank; });
  out["uv"] = Rows<int32_t, 2>(g, [](const Grasp& x) { return std::array<int32_t, 2>{x.u, x.v}; });
  out["clearance_mm"] = Column<double>(g, [](const Grasp& x) { return x.clearance_mm; });
  out["approach_clear"] = Column<bool>(g, [](const Grasp& x) { return x.approach_clear != 0; });
  out["com_offset_mm"] = Column<double>(g, [](const Grasp& x) { return x.com_offset_mm; });
  out["proof"] = Column<int8_t>(g, [](const Grasp& x) { return x.proof; });
  out["proof_swing_deg"] = Column<double>(g, [](const Grasp& x) { return x.proof_swing_deg; });
  out["proof_neighbours_moved_mm"] =
      Column<double>(g, [](const Grasp& x) { return x.proof_neighbours_moved_mm; });
  return out;
}

// the suction and parallel-jaw grasps (config grasps), one array per field over all of each
// kind, each instance's best first
void BindSceneGrasps(SceneClass& scene) {
  using namespace stackgen;
  using namespace stackgen::feed;
  scene.def_property_readonly("suction_grasps", [](const FeedScene& s) {
    const std::vector<suction_grasp>& g = s.message().suction_grasps;
    py::dict out = GraspColumns(g);
    out["point_mm"] = Rows<double, 3>(g, [](const suction_grasp& x) { return x.point_mm; });
    out["normal"] = Rows<double, 3>(g, [](const suction_grasp& x) { return x.normal; });
    out["seal"] = Column<double>(g, [](const suction_grasp& x) { return x.seal; });
    return out;
  });
  scene.def_property_readonly("jaw_grasps", [](const FeedScene& s) {
    const std::vector<jaw_grasp>& g = s.message().jaw_grasps;
    py::dict out = GraspColumns(g);
    out["point_a_mm"] = Rows<double, 3>(g, [](const jaw_grasp& x) { return x.point_a_mm; });
    out["point_b_mm"] = Rows<double, 3>(g, [](const jaw_grasp& x) { return x.point_b_mm; });
    out["approach"] = Rows<double, 3>(g, [](const jaw_grasp& x) { return x.approach; });
    out["width_mm"] = Column<double>(g, [](const jaw_grasp& x) { return x.width_mm; });
    out["cone_margin_deg"] =
        Column<double>(g, [](const jaw_grasp& x) { return x.cone_margin_deg; });
    return out;
  });
}

}  // namespace

PYBIND11_MODULE(_native, m) {
  using namespace stackgen;
  using namespace stackgen::feed;
  m.doc() = "The C++ half of the stackgen package; use the names that `stackgen` exports.";

  // StreamError(RuntimeError) and StreamTimeout(StreamError, TimeoutError)
  stream_error_type = PyErr_NewException("stackgen.StreamError", PyExc_RuntimeError, nullptr);
  PyObject* timeout_bases = PyTuple_Pack(2, stream_error_type, PyExc_TimeoutError);
  stream_timeout_type = PyErr_NewException("stackgen.StreamTimeout", timeout_bases, nullptr);
  Py_DECREF(timeout_bases);
  m.attr("StreamError") = py::handle(stream_error_type);
  m.attr("StreamTimeout") = py::handle(stream_timeout_type);
  py::register_exception_translator([](std::exception_ptr error) {
    try {
      if (error) std::rethrow_exception(error);
    } catch (const FeedTimeout& timeout) {
      PyErr_SetString(stream_timeout_type, timeout.what());
    } catch (const FeedError& failure) {
      PyErr_SetString(stream_error_type, failure.what());
    }
  });

  BindScene(m);
  BindStream(m);
  BindLogAppender(m);
  BindStatusMonitor(m);
  BindLearnerPublisher(m);
  BindFunctions(m);
}
