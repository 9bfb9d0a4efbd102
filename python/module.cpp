// Python bindings (pybind11, numpy): module `particlestream`.
//
//   Archive(path)       an Alembic archive through our reader; points objects' samples as numpy
//                       arrays that view the mapped file (no copy; read-only; they keep the
//                       archive open)
//   cook(input, output, ...)   the cook, with a progress callable; returns its report
//   Clip(path)          a .pstream: layout, a structured numpy dtype, frames as numpy arrays
//   Player(paths, ...)  playback; frame(i) views the player's memory (valid until the next update)
//
// Errors are particlestream.Error (a RuntimeError) with the library's message.
#include <pybind11/functional.h>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>
#include <pybind11/stl/filesystem.h>

#include <cmath>
#include <cstring>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include <fmt/format.h>

#include "base/names.hpp"
#include "particlestream/alembic.hpp"
#include "particlestream/cook.hpp"
#include "particlestream/format.hpp"
#include "particlestream/playback.hpp"

namespace py = pybind11;
using namespace pstream;

namespace {

// A frame handed over as a dict of arrays (cook_particles, FrameSpool.add_frame): 'time' and
// 'position', and optionally 'width', 'velocity', 'id' and 'color'. The arrays it views are made
// C-contiguous float32 (uint64 for ids), converted where they are not, and kept alive in `keep`.
cook::MemoryFrame memory_frame(const py::handle& item, const std::string& name, std::size_t index,
                               std::vector<py::array>& keep) {
  if (!py::isinstance<py::dict>(item))
    throw Error(fmt::format("{}: frame {} is not a dict (time, position, and optionally width, velocity, id, color)",
                            name, index));
  const py::dict f = item.cast<py::dict>();
  if (!f.contains("time") || !f.contains("position"))
    throw Error(fmt::format("{}: frame {} needs 'time' (seconds) and 'position' (N x 3)", name, index));
  const auto floats = [&](const char* key) -> std::span<const float> {
    if (!f.contains(key) || f[key].is_none()) return {};
    auto a = py::array_t<float, py::array::c_style | py::array::forcecast>::ensure(f[key]);
    if (!a) throw Error(fmt::format("{}: frame {}: '{}' is not an array of numbers", name, index, key));
    keep.push_back(a);
    return {a.data(), static_cast<std::size_t>(a.size())};
  };
  cook::MemoryFrame mf;
  mf.time = f["time"].cast<double>();
  mf.position = floats("position");
  mf.count = mf.position.size() / 3;
  mf.width = floats("width");
  mf.velocity = floats("velocity");
  mf.color = floats("color");
  if (f.contains("id") && !f["id"].is_none()) {
    auto a = py::array_t<std::uint64_t, py::array::c_style | py::array::forcecast>::ensure(f["id"]);
    if (!a) throw Error(fmt::format("{}: frame {}: 'id' is not an array of whole numbers", name, index));
    keep.push_back(a);
    mf.id = {a.data(), static_cast<std::size_t>(a.size())};
  }
  // Float attributes of the cook's `attributes`: {"age": (N,), "uvw": (N, 3)}.
  if (f.contains("attributes") && !f["attributes"].is_none()) {
    if (!py::isinstance<py::dict>(f["attributes"]))
      throw Error(fmt::format("{}: frame {}: 'attributes' is not a dict of arrays (name: N or N x k)", name, index));
    for (const auto& [key, value] : f["attributes"].cast<py::dict>()) {
      const std::string attribute = py::str(key);
      auto a = py::array_t<float, py::array::c_style | py::array::forcecast>::ensure(value);
      if (!a || a.ndim() > 2)
        throw Error(
            fmt::format("{}: frame {}: attribute '{}' is not an array of numbers, N or N x k", name, index, attribute));
      keep.push_back(a);
      const auto components = static_cast<std::uint32_t>(a.ndim() == 2 ? a.shape(1) : 1);
      mf.floats.push_back({attribute, components, {a.data(), static_cast<std::size_t>(a.size())}});
    }
  }
  return mf;
}

// cook::FrameSpool for Python: frames added one at a time, kept on disk until cook_particles().
class PyFrameSpool {
 public:
  PyFrameSpool(const std::string& name, const std::optional<std::filesystem::path>& folder)
      : name_(name), spool_(std::in_place, name, folder.value_or(std::filesystem::path{})) {}
  cook::FrameSpool& spool() {
    if (!spool_) throw Error(fmt::format("{}: the frame spool is closed", name_));
    return *spool_;
  }
  void add(const py::object& frame) {
    std::vector<py::array> keep;
    const cook::MemoryFrame f = memory_frame(frame, name_, spool().frames(), keep);
    py::gil_scoped_release release;  // the arrays stay alive in `keep`
    spool().add(f);
  }
  void close() { spool_.reset(); }

 private:
  std::string name_;
  std::optional<cook::FrameSpool> spool_;
};

// Names and messages as Python text: a name in a file need not be valid UTF-8, and an invalid
// byte shows as \xNN instead of raising UnicodeDecodeError.
py::str text(std::string_view s) {
  PyObject* o = PyUnicode_DecodeUTF8(s.data(), static_cast<Py_ssize_t>(s.size()), "backslashreplace");
  if (o == nullptr) throw py::error_already_set();
  return py::reinterpret_steal<py::str>(o);
}

// What the C API refuses, refused here too: a time or a step that is not a finite number.
double finite(double value, const char* what) {
  if (!std::isfinite(value)) throw Error(fmt::format("{} is {}, expected a finite number", what, value));
  return value;
}

// The archive and its points objects, shared by the arrays that view its mapping.
struct PyArchive {
  alembic::Archive archive;
  std::vector<alembic::Object> points;
  explicit PyArchive(const std::filesystem::path& path) : archive(alembic::Archive::open(path)) {
    for (const alembic::Object& o : archive.objects()) {
      if (alembic::Points::matches(o)) points.push_back(o);
    }
  }
  alembic::Points find(const std::string& name) const {
    for (const alembic::Object& o : points) {
      if (o.full_name() == name) return alembic::Points(o);
    }
    throw Error(archive.name() + ": no points object '" + name + "'");
  }
  // The object, checked to have sample `s`.
  alembic::Points find(const std::string& name, std::uint32_t s) const {
    alembic::Points p = find(name);
    if (s >= p.num_samples())
      throw Error(archive.name() + ": " + name + " has no sample " + std::to_string(s) + " (it has " +
                  std::to_string(p.num_samples()) + ")");
    return p;
  }
};

// A read-only array over `view`'s bytes (`columns` values a row; 0: one dimension), owned by
// `owner` (no copy). Stored values that are not the dtype's size are copied instead.
template <class T>
py::array view_array(const alembic::SampleView& view, std::size_t columns, const py::object& owner) {
  const std::size_t n = static_cast<std::size_t>(view.scalar_count());
  std::vector<py::ssize_t> shape = {py::ssize_t(columns ? n / columns : n)};
  if (columns) shape.push_back(py::ssize_t(columns));
  if (view.bytes().size() != n * sizeof(T)) {  // another stored type: converted, a copy
    py::array_t<T> out(shape);
    T* dst = out.mutable_data();
    for (std::size_t i = 0; i < n; ++i)
      dst[i] = std::is_floating_point_v<T> ? T(view.value_f64(i)) : T(view.value_u64(i));
    return out;
  }
  py::array a(py::dtype::of<T>(), shape, {}, view.bytes().data(), owner);
  py::detail::array_proxy(a.ptr())->flags &= ~py::detail::npy_api::NPY_ARRAY_WRITEABLE_;
  return a;
}

// A geometry parameter (.widths, Cd, age, any arbGeomParam) of points object `p` at its sample
// `s`: the parameter's sample nearest to that time, indexed values expanded, as a numpy array
// (N, extent), or (N,) for one value a particle: float32 for floats (float16 widened), float64,
// int64 or uint64 for integers, bool; a list of str for string parameters. Without `expand`, an
// indexed parameter's values as stored (what the official reader's getVals() gives).
py::object read_param(const alembic::Points& p, const alembic::GeomParam& g, std::uint32_t s, bool expand) {
  const double time = p.sample_time(s);
  const alembic::SampleView v = g.values().sample_at(time).first;
  std::vector<std::uint64_t> rows;  // the value row of each element (indexed parameters)
  if (g.indexed() && expand) {
    const alembic::SampleView ix = g.indices().sample_at(time).first;
    rows.resize(ix.scalar_count());
    for (std::size_t i = 0; i < rows.size(); ++i) {
      rows[i] = ix.value_u64(i);
      if (rows[i] >= v.size())
        throw Error(fmt::format("{}: index {} of element {} is past its {} values", g.name(), rows[i], i, v.size()));
    }
  } else {
    rows.resize(v.size());
    for (std::size_t i = 0; i < rows.size(); ++i) rows[i] = i;
  }
  const std::size_t extent = v.extent();
  if (v.pod() == alembic::Pod::String || v.pod() == alembic::Pod::WString) {
    const std::vector<std::string> all = v.strings();
    py::list out;
    for (const std::uint64_t r : rows)
      for (std::size_t k = 0; k < extent; ++k) out.append(text(all[r * extent + k]));
    return out;
  }
  std::vector<py::ssize_t> shape{py::ssize_t(rows.size())};
  if (extent > 1) shape.push_back(py::ssize_t(extent));
  const auto fill = [&](auto tag) {
    using T = decltype(tag);
    py::array_t<T> out(shape);
    T* dst = out.mutable_data();
    for (std::size_t i = 0; i < rows.size(); ++i) {
      for (std::size_t k = 0; k < extent; ++k) {
        const std::uint64_t at = rows[i] * extent + k;
        if constexpr (std::is_same_v<T, std::int64_t>)
          dst[i * extent + k] = v.value_i64(at);
        else if constexpr (std::is_same_v<T, std::uint64_t>)
          dst[i * extent + k] = v.value_u64(at);
        else if constexpr (std::is_same_v<T, bool>)
          dst[i * extent + k] = v.value_u64(at) != 0;
        else
          dst[i * extent + k] = T(v.value_f64(at));
      }
    }
    return py::object(out);
  };
  using alembic::Pod;
  switch (v.pod()) {
    case Pod::Bool: return fill(bool{});
    case Pod::Float16:
    case Pod::Float32: return fill(float{});
    case Pod::Float64: return fill(double{});
    case Pod::Uint8:
    case Pod::Uint16:
    case Pod::Uint32:
    case Pod::Uint64: return fill(std::uint64_t{});
    default: return fill(std::int64_t{});
  }
}

// The numpy dtype of a clip's records: one field per attribute, at its offset.
py::dtype record_dtype(const format::Metadata& m) {
  py::list names, formats, offsets;
  for (const format::Attribute& a : m.layout) {
    const char* base = a.type == format::AttributeType::Float32  ? "<f4"
                       : a.type == format::AttributeType::Unorm8 ? "u1"
                       : a.type == format::AttributeType::Uint32 ? "<u4"
                                                                 : "<u8";
    names.append(text(a.name));
    formats.append(a.components == 1 ? py::str(base) : py::str(std::to_string(a.components) + base));
    offsets.append(a.offset);
  }
  py::dict spec;
  spec["names"] = names;
  spec["formats"] = formats;
  spec["offsets"] = offsets;
  spec["itemsize"] = m.record_size;
  return py::dtype::from_args(spec);
}

py::list layout_of(const format::Metadata& m) {
  py::list out;
  for (const format::Attribute& a : m.layout)
    out.append(py::make_tuple(text(a.name), std::string(format::attribute_type_name(a.type)), a.components, a.offset));
  return out;
}

struct PyClip {
  format::Reader reader;
  py::dtype dtype;  // made once: building a structured dtype costs more than decoding a small frame
  explicit PyClip(const std::filesystem::path& path)
      : reader(format::Reader::open(path)), dtype(record_dtype(reader.metadata())) {}
  // Frame f's entry; throws naming the clip and its frames when there is no frame f.
  const format::FrameEntry& frame(std::uint64_t f) const {
    const format::Metadata& meta = reader.metadata();
    if (f >= meta.frame_count()) {
      throw Error(fmt::format("{}: no frame {} (the clip's frames are 0 to {})", reader.name(), f,
                              static_cast<std::int64_t>(meta.frame_count()) - 1));
    }
    return meta.frames[f];
  }
};

struct PyPlayer {
  std::unique_ptr<playback::Player> player;
  sort::SortMode sort = sort::SortMode::None;
};

}  // namespace

PYBIND11_MODULE(particlestream, m) {
  m.doc() = "ParticleStream: read Alembic point caches, cook them to .pstream, play them back.";
  static py::exception<Error> error(m, "Error", PyExc_RuntimeError);
  // Every failure of the library is particlestream.Error with its message; Python's own errors
  // (a wrong argument type, a numpy error) stay what they are.
  py::register_exception_translator([](std::exception_ptr p) {
    try {
      if (p) std::rethrow_exception(p);
    } catch (const py::error_already_set&) {
      throw;
    } catch (const py::builtin_exception&) {
      throw;
    } catch (const Error& e) {
      PyErr_SetObject(error.ptr(), text(e.what()).ptr());
    } catch (const std::bad_alloc&) {
      PyErr_SetObject(error.ptr(), text("out of memory").ptr());
    } catch (const std::exception& e) {
      PyErr_SetObject(error.ptr(), text(std::string("internal error: ") + e.what()).ptr());
    }
  });
  m.attr("__version__") = "0.1.0";

  py::class_<PyArchive, std::shared_ptr<PyArchive>>(m, "Archive", "An Alembic archive (our reader), mapped.")
      .def(py::init<std::filesystem::path>(), py::arg("path"))
      .def_property_readonly("name", [](const PyArchive& a) { return text(a.archive.name()); })
      .def_property_readonly("start_end_time", [](const PyArchive& a) { return a.archive.start_end_time(); })
      .def(
          "points",
          [](const PyArchive& a) {
            py::list names;
            for (const auto& o : a.points) names.append(text(o.full_name()));
            return names;
          },
          "The full names of the points objects.")
      .def(
          "num_samples", [](const PyArchive& a, const std::string& name) { return a.find(name).num_samples(); },
          py::arg("name"))
      .def(
          "count",
          [](const PyArchive& a, const std::string& name, std::uint32_t s) { return a.find(name, s).count(s); },
          py::arg("name"), py::arg("sample"))
      .def(
          "time",
          [](const PyArchive& a, const std::string& name, std::uint32_t s) { return a.find(name, s).sample_time(s); },
          py::arg("name"), py::arg("sample"))
      .def(
          "positions",
          [](py::object self, const std::string& name, std::uint32_t s) {
            return view_array<float>(self.cast<const PyArchive&>().find(name, s).positions(s), 3, self);
          },
          py::arg("name"), py::arg("sample"),
          "Positions (N, 3) float32, object space: a view of the file (read-only, no copy).")
      .def(
          "ids",
          [](py::object self, const std::string& name, std::uint32_t s) {
            return view_array<std::uint64_t>(self.cast<const PyArchive&>().find(name, s).ids(s), 0, self);
          },
          py::arg("name"), py::arg("sample"), "Ids (N,) uint64 (empty when the object has none).")
      .def(
          "velocities",
          [](py::object self, const std::string& name, std::uint32_t s) {
            const alembic::Points p = self.cast<const PyArchive&>().find(name, s);
            if (!p.has_velocities()) return py::array(py::array_t<float>(std::vector<py::ssize_t>{0, 3}));
            return view_array<float>(p.velocities(s), 3, self);
          },
          py::arg("name"), py::arg("sample"), "Velocities (N, 3) float32 (empty when the object has none).")
      .def(
          "attributes",
          [](const PyArchive& a, const std::string& name) {
            const alembic::Points p = a.find(name);
            py::list names;
            if (p.widths()) names.append(text(p.widths()->name()));
            for (const alembic::GeomParam& g : p.arb_geom_params()) names.append(text(g.name()));
            return names;
          },
          py::arg("name"), "The object's geometry parameters: .widths, then its arbGeomParams (Cd, age, ...).")
      .def(
          "attribute",
          [](const PyArchive& a, const std::string& name, const std::string& attribute, std::uint32_t s, bool expand) {
            const alembic::Points p = a.find(name, s);
            if (p.widths() && (attribute == p.widths()->name() || attribute == "widths"))
              return read_param(p, *p.widths(), s, expand);
            std::string names = p.widths() ? p.widths()->name() : std::string();
            for (const alembic::GeomParam& g : p.arb_geom_params()) {
              if (g.name() == attribute) return read_param(p, g, s, expand);
              names += (names.empty() ? "" : ", ") + g.name();
            }
            throw Error(fmt::format("{}: {} has no attribute '{}' (it has: {})", a.archive.name(), name, attribute,
                                    names.empty() ? "none" : names));
          },
          py::arg("name"), py::arg("attribute"), py::arg("sample"), py::arg("expand") = true,
          "A geometry parameter at a sample of the points object, as the official reader gives it (indexed values "
          "expanded, the parameter's sample nearest to the object's sample time): numpy (N, extent) or (N,), or a "
          "list of str for strings. 'widths' names .widths. expand=False: an indexed parameter's values as stored.");

  // Every option of `pstream cook` but the input's, by the same rules and with the same messages.
  const auto cook_options = [](const std::filesystem::path& output, double fps, const std::string& codec,
                               std::vector<std::string> attributes, const std::string& error,
                               const std::string& scale_error, const std::string& attribute_error,
                               const std::string& frames, const std::string& scale_from, const std::string& color_from,
                               bool velocity, std::uint32_t keyframe_interval, bool drop_invalid, bool store_velocity) {
    cook::Options o;
    if (!frames.empty()) cook::set_frames(o, frames, "frames");
    cook::set_scale_from(o, scale_from, "scale_from");
    o.color_from = color_from;
    o.keep_velocity = velocity;
    o.particle.derive_velocity = !store_velocity;
    o.particle.keyframe_interval = keyframe_interval;
    o.drop_invalid = drop_invalid;
    cook::set_error_bound(o, error, "error");  // the command line's rules
    cook::set_scale_error(o, scale_error, "scale_error");
    cook::set_attribute_error(o, attribute_error, "attribute_error");
    o.output = output;
    o.fps = fps;
    o.attributes = std::move(attributes);
    cook::set_codec(o, codec);
    return o;
  };
  // Runs a cook with the GIL released, reporting progress(done, total) from it: the cook's work in
  // frames, each frame counted once for each pass over it (the particle codec's scan for its
  // statistics, then the write), so that `done` only grows and ends at `total`.
  const auto run_cook = [](const std::function<cook::Report(const std::function<void(const cook::Progress&)>&)>& cook,
                           const std::function<void(std::uint64_t, std::uint64_t)>& progress) {
    std::function<void(const cook::Progress&)> report;
    bool scanned = false;  // a scan came first: two passes
    if (progress) {
      report = [&](const cook::Progress& p) {
        if (p.stage == cook::Stage::Fetch) return;  // bytes, not frames
        scanned = scanned || p.stage == cook::Stage::Scan;
        const std::uint64_t before = scanned && p.stage == cook::Stage::Write ? p.frame_count : 0;
        py::gil_scoped_acquire gil;
        progress(before + p.frames_done, (scanned ? 2 : 1) * p.frame_count);
      };
    }
    cook::Report r;
    {
      py::gil_scoped_release release;
      r = cook(report);
    }
    py::dict d;
    d["frames"] = r.frames;
    d["particles"] = r.particles;
    d["file_bytes"] = r.file_bytes;
    d["seconds"] = r.seconds;
    d["object"] = r.object;
    d["mesh_vertices"] = r.mesh_vertices;
    return d;
  };

  m.def(
      "cook",
      [cook_options, run_cook](const std::filesystem::path& input, const std::filesystem::path& output, double fps,
                               const std::string& codec, std::vector<std::string> attributes, const std::string& object,
                               bool interpolate, const std::function<void(std::uint64_t, std::uint64_t)>& progress,
                               const std::string& error, const std::string& scale_error,
                               const std::string& attribute_error, const std::string& frames, bool merge,
                               const std::string& scale_from, const std::string& color_from, bool velocity,
                               std::uint32_t keyframe_interval, bool drop_invalid, bool store_velocity) {
        cook::Options o =
            cook_options(output, fps, codec, std::move(attributes), error, scale_error, attribute_error, frames,
                         scale_from, color_from, velocity, keyframe_interval, drop_invalid, store_velocity);
        o.input = input;
        o.object = object;
        o.merge = merge;
        o.interpolate = interpolate;
        return run_cook([&](const auto& report) { return cook::cook(o, report); }, progress);
      },
      py::arg("input"), py::arg("output"), py::arg("fps") = 0.0, py::arg("codec") = "particle",
      py::arg("attributes") = std::vector<std::string>{}, py::arg("object") = "", py::arg("interpolate") = false,
      py::arg("progress") = nullptr, py::arg("error") = "1e-4", py::arg("scale_error") = "1%",
      py::arg("attribute_error") = "1e-3", py::arg("frames") = "", py::arg("merge") = false,
      py::arg("scale_from") = "widths", py::arg("color_from") = "auto", py::arg("velocity") = true,
      py::arg("keyframe_interval") = format::kDefaultKeyframeInterval, py::arg("drop_invalid") = false,
      py::arg("store_velocity") = false,
      "Cooks an Alembic archive (or a PLY sequence) into a .pstream. progress(done, total) is "
      "called after each frame of each pass over the frames: total counts every frame once a pass (twice with "
      "the particle codec, which reads the frames for their statistics before it encodes them), so done only "
      "grows and ends at total. The particle codec's bounds are the command line's --error (a fraction of the "
      "bounds diagonal, 'rel:1e-4', or 'abs:0.001' in scene units) and --scale-error (each scale relative to "
      "itself: '1%') and --attribute-error (velocity and other floats, a fraction of their range: '1e-3'). The "
      "other options are the command line's too: frames ('A:B'), object, merge, scale_from ('widths', "
      "'constant:X', 'attr:NAME'), color_from ('auto', 'Cd', 'none'), attributes, velocity (give the clip a "
      "velocity: --no-velocity is velocity=False), keyframe_interval, drop_invalid, store_velocity "
      "(--store-velocity: store the source's instead of deriving it from particles with ids). Returns the "
      "report (frames, particles, file_bytes, seconds, object: what was cooked, mesh_vertices: whether it is a "
      "mesh's vertices, as an archive without points objects and with one mesh cooks).");

  py::class_<PyFrameSpool>(
      m, "FrameSpool",
      "Frames added one at a time and kept on disk, not in memory, until cook_particles(spool, ...) cooks them: "
      "for simulations larger than memory (the Blender add-on exports through one). The frames' arrays go to an "
      "unnamed temporary file in `folder` (default: the system's temporary folder), which leaves nothing behind, "
      "even when the process is killed; the spool itself holds 24 bytes a frame. Use it as a context manager, or "
      "call close().")
      .def(py::init<const std::string&, const std::optional<std::filesystem::path>&>(), py::arg("name") = "particles",
           py::arg("folder") = py::none(),
           "name: for messages about the frames; folder: where the temporary file lives (a disk with room for "
           "about 40 bytes a particle a frame).")
      .def("add_frame", &PyFrameSpool::add, py::arg("frame"),
           "Checks and writes one frame: a dict as cook_particles takes ('time', 'position', and optionally "
           "'width', 'velocity', 'id', 'color'), with the same attributes as the frames before it and a later "
           "time. A refused frame leaves the spool as it was.")
      .def(
          "drop_ids", [](PyFrameSpool& s) { s.spool().drop_ids(); },
          "Cook without the ids added (a mesh whose vertex count changes has vertex indices, not ids).")
      .def_property_readonly("frames", [](PyFrameSpool& s) { return s.spool().frames(); })
      .def_property_readonly(
          "bytes", [](PyFrameSpool& s) { return s.spool().bytes(); }, "Bytes written to the temporary file so far.")
      .def("close", &PyFrameSpool::close, "Releases the temporary file (its disk space).")
      .def(
          "__enter__", [](PyFrameSpool& s) -> PyFrameSpool& { return s; }, py::return_value_policy::reference)
      .def("__exit__", [](PyFrameSpool& s, const py::args&) { s.close(); });

  m.def(
      "cook_particles",
      [cook_options, run_cook](
          const py::object& frames, const std::filesystem::path& output, double fps, const std::string& name,
          const std::string& object, const std::string& codec, std::vector<std::string> attributes,
          const std::function<void(std::uint64_t, std::uint64_t)>& progress, const std::string& error,
          const std::string& scale_error, const std::string& attribute_error, const std::string& frame_range,
          const std::string& scale_from, const std::string& color_from, bool velocity, std::uint32_t keyframe_interval,
          bool drop_invalid, bool store_velocity) {
        cook::Options o =
            cook_options(output, 0.0, codec, std::move(attributes), error, scale_error, attribute_error, frame_range,
                         scale_from, color_from, velocity, keyframe_interval, drop_invalid, store_velocity);
        cook::MemoryClip clip;
        std::vector<py::array> keep;  // the arrays the frames view, converted where they had to be
        if (py::isinstance<PyFrameSpool>(frames)) {
          clip = frames.cast<PyFrameSpool&>().spool().clip(object, fps);
        } else {
          const py::sequence list = frames.cast<py::sequence>();
          for (std::size_t i = 0; i < list.size(); ++i) clip.frames.push_back(memory_frame(list[i], name, i, keep));
          clip.object = object;
          clip.fps = fps;
        }
        clip.name = name;
        return run_cook([&](const auto& report) { return cook::cook(o, clip, report); }, progress);
      },
      py::arg("frames"), py::arg("output"), py::arg("fps") = 24.0, py::arg("name") = "particles",
      py::arg("object") = "", py::arg("codec") = "particle", py::arg("attributes") = std::vector<std::string>{},
      py::arg("progress") = nullptr, py::arg("error") = "1e-4", py::arg("scale_error") = "1%",
      py::arg("attribute_error") = "1e-3", py::arg("frame_range") = "", py::arg("scale_from") = "widths",
      py::arg("color_from") = "auto", py::arg("velocity") = true,
      py::arg("keyframe_interval") = format::kDefaultKeyframeInterval, py::arg("drop_invalid") = false,
      py::arg("store_velocity") = false,
      "Cooks particles held in memory (a DCC's evaluated particles, a script's simulation) into a .pstream, as "
      "cook() cooks a file. frames: a FrameSpool, or a sequence of dicts, one per frame in increasing time, each with "
      "'time' "
      "(seconds) and 'position' (N x 3), and optionally 'width' (N, diameters: the record's scale is half), "
      "'velocity' (N x 3, units per second), 'id' (N, stable across frames: matching and derived velocity need "
      "them), 'color' (N x 4, linear RGBA in 0..1) and 'attributes' (a dict of float arrays, N or N x k, stored "
      "when `attributes` names them); an attribute is in every frame with particles or in none. "
      "fps is the frames' rate; name and object are recorded as the clip's source. The other options are cook()'s "
      "(frame_range is its `frames`). Returns the report (frames, particles, file_bytes, seconds).");

  m.def(
      "verify",
      [](const std::string& clip, const std::string& against) {
        cook::VerifyReport r;
        {
          py::gil_scoped_release release;
          r = cook::verify(clip, against);
        }
        py::list attributes;
        for (const cook::AttributeCheck& a : r.attributes) {
          py::dict d;
          d["name"] = a.name;
          d["max_error"] = a.max_error;
          d["bound"] = a.exact ? 0.0 : a.bound;
          d["relative"] = a.relative;
          d["exact"] = a.exact;
          d["ok"] = a.ok;
          if (a.counted) {
            d["distinct_source"] = a.distinct_source;
            d["distinct_counted_up_to"] = cook::kDistinctValuesCounted;
            d["distinct_clip"] = a.distinct_clip;
            d["kept_apart"] = a.kept_apart;
          }
          d["derived"] = a.derived;
          if (a.derived) {
            d["in_source"] = a.in_source;
            d["rms_error"] = a.rms_error;
            d["rms_source"] = a.rms_source;
          }
          attributes.append(d);
        }
        py::dict d;
        d["ok"] = r.ok();
        d["frames"] = r.frames;
        d["chunks_verified"] = r.chunks_verified;
        d["errors"] = r.errors;
        d["source"] = r.source;
        d["frames_compared"] = r.frames_compared;
        d["particles_compared"] = r.particles_compared;
        d["attributes"] = attributes;
        return d;
      },
      py::arg("clip"), py::arg("against") = "",
      "Checks a .pstream as `pstream verify` does: every checksum, index entry and frame, and with `against` "
      "(its source, .abc or a PLY sequence) every attribute of every frame against the source cooked again, "
      "each within its own bound. Returns the report: ok, frames, chunks_verified, errors (each names the "
      "chunk, frame or attribute), and per attribute its max_error, bound, relative, exact, ok and distinct "
      "values in the source and the clip; a derived velocity (derived=True) has no bound: its rms_error "
      "against the source's velocities (in_source) and their rms_source.");

  m.def(
      "describe_ply",
      [](const std::filesystem::path& file) {
        cook::PlySequenceInfo s;
        {
          py::gil_scoped_release release;
          s = cook::describe_ply_sequence(file);
        }
        py::list files, properties;
        for (std::size_t i = 0; i < s.files.size(); ++i) {
          py::dict f;
          f["file"] = s.files[i].string();
          f["count"] = s.counts[i];
          files.append(f);
        }
        for (const auto& p : s.properties) properties.append(py::make_tuple(p.name, p.type));
        py::dict d;
        d["encoding"] = s.format;
        d["first_number"] = s.first_number;
        d["files"] = files;
        d["bytes"] = s.bytes;
        d["properties"] = properties;
        d["scale_from"] = s.scale_property;
        d["scale_is_diameter"] = s.scale_is_diameter;
        d["color"] = s.has_color;
        d["velocity"] = s.has_velocity;
        d["ids"] = s.has_ids;
        return d;
      },
      py::arg("file"),
      "Describes the numbered PLY sequence `file` belongs to, as `pstream info frame.0001.ply` does and as "
      "cook() will read it, from the files' headers: encoding ('ascii' or 'binary_little_endian'), "
      "first_number, files (each its file and vertex count, in frame order), bytes, properties ((name, type) "
      "pairs), and what a cook takes: scale_from (the property, '' for none), scale_is_diameter, color, "
      "velocity, ids. A missing frame or a file unlike the first raises particlestream.Error as cook() would.");

  m.def(
      "export",
      [](const std::string& clip, const std::filesystem::path& output,
         const std::function<void(std::uint64_t, std::uint64_t)>& progress, const std::string& frames) {
        cook::ExportOptions o;
        o.input = clip;
        o.output = output;
        if (!frames.empty()) std::tie(o.frame_begin, o.frame_end) = pstream::parse_frame_range(frames, "frames");
        std::function<void(std::uint64_t, std::uint64_t)> report;
        if (progress) {
          report = [&](std::uint64_t done, std::uint64_t total) {
            py::gil_scoped_acquire gil;
            progress(done, total);
          };
        }
        cook::ExportReport r;
        {
          py::gil_scoped_release release;
          r = cook::export_clip(o, report);
        }
        py::dict d;
        d["format"] = r.ply ? "ply" : "alembic";
        d["frames"] = r.frames;
        d["first"] = r.first.string();
        d["bytes_written"] = r.bytes_written;
        return d;
      },
      py::arg("clip"), py::arg("output"), py::arg("progress") = nullptr, py::arg("frames") = "",
      "Writes a .pstream (a path or URL) back out for a DCC, as `pstream export` does; the output's "
      "extension chooses the format: NAME.abc an Alembic points cache (P, ids, velocities, widths = 2 x "
      "scale, Cd, other float attributes), NAME.ply a binary PLY sequence NAME.0001.ply, NAME.0002.ply ... "
      "progress(frames_done, frame_count) is called after each frame; frames: 'A:B' the clip's frames from A up to "
      "but not including B (a PLY file keeps its frame's number). Returns the report (format, frames, first: the "
      "file or the sequence's first, bytes_written).");

  py::class_<PyClip>(m, "Clip", "A .pstream read directly.")
      .def(py::init<std::filesystem::path>(), py::arg("path"))
      .def_property_readonly("frame_count", [](const PyClip& c) { return c.reader.metadata().frame_count(); })
      .def_property_readonly("fps", [](const PyClip& c) { return c.reader.metadata().fps; })
      .def_property_readonly("record_size", [](const PyClip& c) { return c.reader.metadata().record_size; })
      .def_property_readonly(
          "max_count", [](const PyClip& c) { return c.reader.metadata().max_count; },
          "The most particles in any frame: room enough for read_frame(f, out=...).")
      .def_property_readonly(
          "layout", [](const PyClip& c) { return layout_of(c.reader.metadata()); },
          "[(name, type, components, offset)]")
      .def_property_readonly("dtype", [](const PyClip& c) { return c.dtype; })
      .def_property_readonly(
          "frames_decoded", [](const PyClip& c) { return c.reader.frames_decoded(); },
          "The frames read_frame() has decoded so far, those decoded on the way to the ones asked for "
          "included (a predicted frame decodes on from its keyframe or a frame before it).")
      .def(
          "count", [](const PyClip& c, std::uint64_t f) { return c.frame(f).count; }, py::arg("frame"))
      .def(
          "time", [](const PyClip& c, std::uint64_t f) { return c.frame(f).time; }, py::arg("frame"))
      .def(
          "read_frame",
          [](PyClip& c, std::uint64_t f, const py::object& out) -> py::array {
            const format::Metadata& meta = c.reader.metadata();
            const std::uint64_t n = c.frame(f).count;
            const std::size_t bytes = static_cast<std::size_t>(n * meta.record_size);
            if (out.is_none()) {  // decoded straight into the array it returns
              py::array records(c.dtype, std::vector<py::ssize_t>{py::ssize_t(n)});
              c.reader.read_frame(f, {static_cast<std::byte*>(records.mutable_data()), bytes});
              return records;
            }
            // The caller's array, reused from frame to frame: checked, never converted (a
            // converted copy would take the frame and be thrown away).
            const std::string what = fmt::format("{}: read_frame({}, out=...): ", c.reader.name(), f);
            if (!py::isinstance<py::array>(out))
              throw Error(what + "out must be a numpy array of the clip's dtype, not " +
                          py::repr(out.get_type()).cast<std::string>());
            auto a = py::reinterpret_borrow<py::array>(out);
            if (!a.dtype().equal(c.dtype))
              throw Error(what + "out's dtype is " + py::repr(a.dtype()).cast<std::string>() + ", expected clip.dtype");
            if (a.ndim() != 1 || (a.flags() & py::array::c_style) == 0 || !a.writeable())
              throw Error(what + "out must be a writable, contiguous one-dimensional array");
            if (std::uint64_t(a.shape(0)) < n) {
              throw Error(what + fmt::format("frame {} holds {} particles, out has room for {}", f, n, a.shape(0)));
            }
            c.reader.read_frame(f, {static_cast<std::byte*>(a.mutable_data()), bytes});
            return a[py::slice(0, py::ssize_t(n), 1)];
          },
          py::arg("frame"), py::arg("out") = py::none(),
          "Frame `frame`'s records as a structured array of `dtype`: a new array, or, with `out` (a "
          "writable, contiguous 1-D array of `dtype` with room for the frame, e.g. "
          "numpy.empty(clip.max_count, clip.dtype)), the view out[:count] of it, so that a loop over "
          "frames allocates no records.");

  py::class_<PyPlayer>(m, "Player", "Playback of one or more clips (the C++ playback::Player).")
      .def(py::init([](std::vector<std::filesystem::path> paths, const std::string& interpolation, bool blocking,
                       bool loop, const std::string& sort, double cache_seconds, long long saved_states) {
             if (!(cache_seconds >= 0.0) || !std::isfinite(cache_seconds))  // as the C API
               throw Error(fmt::format("cache_seconds is {}, expected a finite number >= 0", cache_seconds));
             if (saved_states < 0) throw Error(fmt::format("saved_states is {}, expected 0 or more", saved_states));
             playback::PlayerOptions o;
             o.interpolation = playback::parse_interpolation(interpolation);
             o.stream.blocking = blocking;
             o.stream.cache_seconds = cache_seconds;
             o.stream.saved_states = static_cast<std::size_t>(saved_states);
             o.loop = loop;
             auto p = std::make_unique<PyPlayer>();
             p->sort = sort::parse_sort_mode(sort);
             p->player = playback::Player::open(paths, std::move(o));
             return p;
           }),
           py::arg("paths"), py::arg("interpolation") = "hermite", py::arg("blocking") = true, py::arg("loop") = true,
           py::arg("sort") = "none", py::arg("cache_seconds") = 1.0,
           py::arg("saved_states") = static_cast<long long>(stream::StreamOptions{}.saved_states),
           "saved_states: decoder states kept for playing backwards (and seeking back) within a keyframe group; "
           "each holds about 8 bytes per particle and coded word; 0 decodes every frame shown backwards from "
           "its keyframe.")
      .def("play", [](PyPlayer& p) { p.player->play(); })
      .def("pause", [](PyPlayer& p) { p.player->pause(); })
      .def(
          "seek", [](PyPlayer& p, double t) { p.player->seek(finite(t, "seek: time")); }, py::arg("time"))
      .def(
          "set_speed", [](PyPlayer& p, double s) { p.player->set_speed(finite(s, "set_speed: speed")); },
          py::arg("speed"))
      .def(
          "set_loop", [](PyPlayer& p, bool l) { p.player->set_loop(l); }, py::arg("loop"))
      .def(
          "set_range",
          [](PyPlayer& p, double a, double b) {
            p.player->set_range(finite(a, "set_range: start"), finite(b, "set_range: end"));
          },
          py::arg("start"), py::arg("end"))
      .def_property_readonly("clip_count", [](const PyPlayer& p) { return p.player->clip_count(); })
      .def(
          "time", [](const PyPlayer& p, std::size_t i) { return p.player->clip(i).time(); }, py::arg("clip") = 0)
      .def(
          "update",
          [](PyPlayer& p, double dt,
             std::optional<py::array_t<float, py::array::c_style | py::array::forcecast>> view) {
            if (!(dt >= 0.0) || !std::isfinite(dt))
              throw Error(fmt::format("update: dt is {}, expected a finite number >= 0", dt));
            render::Mat4 v = render::identity();
            if (view) {  // numpy's M[row, col] (M @ p), to the column-major Mat4
              if (view->ndim() != 2 || view->shape(0) != 4 || view->shape(1) != 4)
                throw Error("view must be a 4x4 matrix (world -> view)");
              const auto m = view->unchecked<2>();
              for (py::ssize_t r = 0; r < 4; ++r)
                for (py::ssize_t c = 0; c < 4; ++c) v[std::size_t(c * 4 + r)] = m(r, c);
            }
            const playback::FrameStats& s = p.player->advance(dt, v, p.sort);
            p.player->check();
            py::dict d;
            d["stream_ms"] = s.stream_ms;
            d["interpolate_ms"] = s.interpolate_ms;
            d["sort_ms"] = s.sort_ms;
            d["particles"] = s.particles;
            return d;
          },
          py::arg("dt"), py::arg("view") = py::none(),
          "Advances every clip by dt seconds, interpolates, and sorts for `view` (a 4x4 world -> view matrix, "
          "M @ p; default identity) as the player's `sort` says; raises the error of a clip that failed.")
      .def(
          "order",
          [](py::object self, std::size_t clip) {
            const PyPlayer& p = self.cast<const PyPlayer&>();
            if (clip >= p.player->clip_count()) throw Error("no clip " + std::to_string(clip));
            const std::ptrdiff_t b = p.player->batch_of(clip);
            if (b < 0) return py::array_t<std::uint32_t>(0);
            const std::span<const std::uint32_t> order = p.player->batches()[std::size_t(b)].order;
            py::array_t<std::uint32_t> a({py::ssize_t(order.size())}, {py::ssize_t(sizeof(std::uint32_t))},
                                         order.data(), self);
            py::detail::array_proxy(a.ptr())->flags &= ~py::detail::npy_api::NPY_ARRAY_WRITEABLE_;
            return a;
          },
          py::arg("clip") = 0,
          "Clip i's draw order from the last update() (indices into frame(i), back to front for sort='back'); "
          "empty when it is drawn in stored order. A read-only view, valid until the next update().")
      .def(
          "stats",
          [](const PyPlayer& p, std::size_t clip) {
            if (clip >= p.player->clip_count()) throw Error("no clip " + std::to_string(clip));
            const stream::DebugInfo d = p.player->clip(clip).debug();
            py::dict out;
            out["stalls"] = d.stalls;
            out["loads_done"] = d.loads_done;
            out["bytes_read"] = d.bytes_read;
            out["frames_decoded"] = d.frames_decoded;
            out["io_ms"] = d.io_ms;
            out["decode_ms"] = d.decode_ms;
            out["cache_bytes"] = d.cache_bytes;
            out["decode_bytes"] = d.decode_bytes;
            return out;
          },
          py::arg("clip") = 0,
          "Clip i's streaming counters since open: stalls, loads, bytes read, frames decoded, IO and decode time, "
          "and the memory it holds (cache_bytes + decode_bytes, fixed at open).")
      .def(
          "frame",
          [](py::object self, std::size_t clip) {
            const PyPlayer& p = self.cast<const PyPlayer&>();
            if (clip >= p.player->clip_count()) throw Error("no clip " + std::to_string(clip));
            const format::Metadata& meta = p.player->clip(clip).metadata();
            const std::ptrdiff_t b = p.player->batch_of(clip);
            if (b < 0) return py::array(record_dtype(meta), std::vector<py::ssize_t>{0});
            const render::ParticleBatch& batch = p.player->batches()[std::size_t(b)];
            py::array a(record_dtype(meta), std::vector<py::ssize_t>{py::ssize_t(batch.count)}, {}, batch.first.data(),
                        self);
            py::detail::array_proxy(a.ptr())->flags &= ~py::detail::npy_api::NPY_ARRAY_WRITEABLE_;
            return a;
          },
          py::arg("clip") = 0,
          "Clip i's records as update() left them: a read-only view of the player's memory (no copy), valid "
          "until the next update().");
}
