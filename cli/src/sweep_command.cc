// `bflow sweep`: a scene's flow and B-derivative over a grid of initial states and parameters
// (bflow::SweepGrid), on a pool of threads (bflow::run_ordered), one record per sample in grid
// order, streamed to the output as the samples complete.
//
// Every option is validated before the first sample runs, the varied parameters included (the
// scene is built at both ends of each --vary-param axis), so that bad input is exit code 2 with
// nothing written. A sample that fails (a start on a surface, grazing, sliding, an integration
// that stops early) is a record with its status and message; the sweep goes on and exits with 0.
// The last line on `err` counts the samples by status.
#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <exception>
#include <filesystem>
#include <fstream>
#include <functional>
#include <map>
#include <memory>
#include <new>
#include <ostream>
#include <sstream>
#include <string>
#include <system_error>
#include <thread>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "bflow/core/errors.h"
#include "bflow/sweep/mpi.h"
#include "bflow/sweep/parallel.h"
#include "bflow/sweep/sweep.h"
#include "cli_commands.h"
#include "cli_json.h"
#include "cli_util.h"
#include "demo_util.h"
#include "scene_setup.h"

namespace bflow::cli {
namespace {

struct AxisText {
  std::string key;
  double lo = 0.0, hi = 0.0;
  std::uint64_t count = 1;
};

// "key=lo:hi:count".
AxisText parse_axis(const std::string& text, const std::string& option) {
  const auto equals = text.find('=');
  if (equals == std::string::npos || equals == 0) {
    fail(option, quote(text) + " is not KEY=LO:HI:COUNT");
  }
  AxisText axis;
  axis.key = trimmed(text.substr(0, equals));
  const std::string range = text.substr(equals + 1);
  const auto first = range.find(':');
  const auto second = first == std::string::npos ? first : range.find(':', first + 1);
  if (second == std::string::npos || range.find(':', second + 1) != std::string::npos) {
    fail(option, quote(text) + " is not KEY=LO:HI:COUNT (three fields after '=')");
  }
  axis.lo = parse_number(range.substr(0, first), option + " " + axis.key + " lo");
  axis.hi =
      parse_number(range.substr(first + 1, second - first - 1), option + " " + axis.key + " hi");
  axis.count = parse_unsigned(range.substr(second + 1), option + " " + axis.key + " count",
                              std::uint64_t{1} << 53);
  if (axis.count < 1) fail(option, axis.key + " count must be >= 1, got 0");
  return axis;
}

std::string duration_text(double seconds) {
  if (seconds < 0.0) return "?";
  if (seconds < 60.0) return format_number(std::round(seconds)) + " s";
  if (seconds < 3600.0) return format_number(std::floor(seconds / 60.0)) + " min";
  return format_number(std::floor(seconds / 360.0) / 10.0) + " h";
}

// One line, rewritten in place: "[=====>     ] 1234/10000 samples  523/s  about 17 s left".
void draw_progress(std::ostream& err, const SweepProgress& p) {
  constexpr int kWidth = 30;
  const double fraction =
      p.total > 0 ? static_cast<double>(p.done) / static_cast<double>(p.total) : 1.0;
  const int filled = static_cast<int>(fraction * kWidth);
  std::string bar(static_cast<std::size_t>(kWidth), ' ');
  for (int k = 0; k < filled; ++k) bar[static_cast<std::size_t>(k)] = '=';
  if (filled < kWidth) bar[static_cast<std::size_t>(filled)] = '>';
  char rate[32];
  std::snprintf(rate, sizeof rate, "%.1f", p.rate());
  err << "\r[" << bar << "] " << p.done << '/' << p.total << " samples  " << rate << "/s  ";
  if (p.done < p.total) {
    err << "about " << duration_text(p.seconds_left()) << " left  ";
  } else {
    err << "in " << duration_text(p.seconds) << "            \n";
  }
  err.flush();
}

namespace fs = std::filesystem;

const MpiSession* g_mpi = nullptr;

// The records could not be written; the message names the output and the reason. Exit code 1.
class WriteError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// What an earlier run left in `path` to keep (--resume); refused (exit 2, the file untouched)
// unless it is a regular file holding an output of this very sweep.
SweepResumePoint resume_point(const std::string& path, const SweepWriter& writer) {
  std::error_code code;
  const fs::file_status status = fs::status(path, code);
  if (!fs::exists(status)) return {};
  if (!fs::is_regular_file(status)) {
    fail("--resume", quote(path, 200) + " is not a regular file; only a file an earlier run " +
                         "of this sweep wrote can be resumed");
  }
  errno = 0;
  std::ifstream earlier(path, std::ios::binary);
  if (!earlier) fail("--resume", "cannot read " + quote(path, 200) + ": " + std::strerror(errno));
  SweepResumePoint point;
  try {
    point = find_resume_point(earlier, writer);
  } catch (const InvalidArgument& e) {
    fail("--resume",
         quote(path, 200) + ": " + std::string(e.what()).substr(std::string("sweep: ").size()));
  }
  if (earlier.bad()) fail("--resume", "reading " + quote(path, 200) + " failed");
  return point;
}

struct AtlasPoint {
  double x = 0.0, y = 0.0;
  std::string structure;
  bool grouped = false, failed = false;
};

// A gnuplot title, quoted for a single-quoted string (noenhanced: '_' stays itself).
std::string gnuplot_text(std::string text) {
  std::string quoted;
  for (char c : text) quoted += c == '\'' ? std::string("''") : std::string(1, c);
  return "'" + quoted + "'";
}

// The atlas: one colour per event structure (in order of first appearance in the grid), open
// black squares over the samples with a group of surfaces crossed together, black crosses on
// the failed ones. Writes STEM.dat and STEM.gp beside the PNG and runs gnuplot.
void draw_atlas(const std::filesystem::path& png, const SweepGrid& grid,
                const std::vector<AtlasPoint>& points, const Eigen::VectorXd& dx) {
  std::map<std::string, int> ids;
  std::vector<std::string> labels;
  std::ostringstream data;
  data << "# " << grid.axes()[0].name() << ' ' << grid.axes()[1].name()
       << " structure grouped failed\n";
  for (const AtlasPoint& p : points) {
    const auto [it, added] = ids.emplace(p.structure, static_cast<int>(ids.size()));
    if (added) labels.push_back(p.structure);
    data << format_number(p.x) << ' ' << format_number(p.y) << ' ' << it->second << ' '
         << (p.grouped ? 1 : 0) << ' ' << (p.failed ? 1 : 0) << '\n';
  }
  const std::filesystem::path dir = png.has_parent_path() ? png.parent_path() : ".";
  const std::string stem = png.stem().string();
  write_file(dir / (stem + ".dat"), data.str(), "sweep");
  static const char* const kColours[] = {"#1f77b4", "#ff7f0e", "#2ca02c", "#d62728",
                                         "#9467bd", "#8c564b", "#e377c2", "#7f7f7f",
                                         "#bcbd22", "#17becf", "#393b79", "#ad494a"};
  const double cells = static_cast<double>(std::max(grid.axes()[0].count, grid.axes()[1].count));
  const double size = std::min(3.0, std::max(0.3, 60.0 / cells));
  std::ostringstream gp;
  gp << "# The atlas of crossing orders written by bflow sweep --atlas; run: gnuplot " << stem
     << ".gp\n"
     << "set terminal pngcairo size 1100,800 noenhanced font 'Sans,11'\n"
     << gnuplot_output(png.filename().string()) << "set title "
     << gnuplot_text("Event structure along dx = " + format_vector(dx)) << "\n"
     << "set xlabel " << gnuplot_text(grid.axes()[0].name()) << "\n"
     << "set ylabel " << gnuplot_text(grid.axes()[1].name()) << "\n"
     << "set key outside right top\nset grid\n"
     << "plot \\\n";
  const std::string file = gnuplot_text(stem + ".dat");
  for (std::size_t k = 0; k < labels.size(); ++k) {
    gp << "  " << file << " using ($3 == " << k << " ? $1 : NaN):2 with points pt 5 ps " << size
       << " lc rgb '" << kColours[k % 12] << "' title " << gnuplot_text(labels[k]) << ", \\\n";
  }
  gp << "  " << file << " using ($4 == 1 ? $1 : NaN):2 with points pt 4 ps " << size
     << " lc rgb 'black' title 'surfaces crossed together', \\\n"
     << "  " << file << " using ($5 == 1 ? $1 : NaN):2 with points pt 2 ps " << size
     << " lc rgb 'black' title 'failed'\n";
  write_file(dir / (stem + ".gp"), gp.str(), "sweep");
  run_gnuplot(dir, stem + ".gp", png.filename().string(), "sweep", "leave out --atlas");
}

int sweep_command(const SweepCommandOptions& options, std::ostream& out, std::ostream& err) {
  const SceneSetup setup = parse_scene_setup(options.flow);
  const Request& request = setup.request;

  int threads = 0;
  if (options.threads) {
    threads = static_cast<int>(parse_unsigned(*options.threads, "--threads", 4096));
    if (threads < 1) fail("--threads", "must be >= 1, got 0");
  } else if (g_mpi != nullptr && g_mpi->size() > 1) {
    // Under MPI the ranks on one machine share its cores.
    const char* local = std::getenv("OMPI_COMM_WORLD_LOCAL_SIZE");
    const int per_node = local != nullptr ? std::max(1, std::atoi(local)) : 1;
    const int cores = static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
    threads = std::max(1, cores / per_node);
  }
  SweepFormat format = SweepFormat::kJsonLines;
  try {
    format = parse_sweep_format(options.format);
  } catch (const InvalidArgument& e) {
    fail("--format", std::string(e.what()).substr(std::string("sweep: ").size()));
  }

  // d and the default x0 from the scene as given; every varied parameter checked at both ends.
  const std::pair<int, Eigen::VectorXd> scene_start =
      with_scene(setup, {}, [](const SegmentModel& model, const Eigen::VectorXd& start) {
        return std::make_pair(model.states(), start);
      });
  const int d = scene_start.first;
  const Eigen::VectorXd& default_x0 = scene_start.second;
  std::vector<SweepAxis> axes;
  std::map<std::string, std::string> varied_by;  // axis name -> the option that varies it
  const auto claim = [&](const std::string& name, const std::string& option) {
    const auto [it, added] = varied_by.emplace(name, option);
    if (!added) {
      fail(option, name + " is already varied by " + it->second + "; vary each once");
    }
  };
  for (std::size_t k = 0; k < options.vary.size(); ++k) {
    const std::string option = "--vary[" + std::to_string(k) + "]";
    const AxisText a = parse_axis(options.vary[k], option);
    const std::uint64_t index = parse_unsigned(a.key, option + " index", 1u << 30);
    if (index >= static_cast<std::uint64_t>(d)) {
      fail(option, "state index " + std::to_string(index) +
                       " is outside x0 (d = " + std::to_string(d) + ")");
    }
    axes.push_back(SweepAxis::state_axis(static_cast<int>(index), a.lo, a.hi, a.count));
    claim(axes.back().name(), option);
  }
  // The scenes' real parameters are valid on intervals, their integer ones (seed) at whole
  // numbers, so an axis whose ends and second value are valid is valid everywhere: those three
  // are built, one axis at a time, then all axes together (parameters that exclude each other).
  const auto probe_scene = [&](const Params& overrides, const std::string& option) {
    int states = 0;
    try {
      states = with_scene(setup, overrides, [](const SegmentModel& model, const Eigen::VectorXd&) {
        return model.states();
      });
    } catch (const InputError& e) {
      fail(option, std::string(e.what()).substr(std::string("--param: ").size()));
    } catch (const InvalidArgument& e) {
      fail(option, e.what());
    }
    return states;
  };
  std::vector<AxisText> parameter_axes;
  for (std::size_t k = 0; k < options.vary_param.size(); ++k) {
    const std::string option = "--vary-param[" + std::to_string(k) + "]";
    const AxisText a = parse_axis(options.vary_param[k], option);
    claim(a.key, option);
    for (const auto& [key, value] : setup.params) {
      if (key == a.key) {
        fail(option, a.key + " is also fixed by --param " + a.key + "=" + quote(value) +
                         "; give it either fixed or varied");
      }
    }
    const SweepAxis axis = SweepAxis::parameter_axis(a.key, a.lo, a.hi, a.count);
    for (const std::uint64_t probe : {std::uint64_t{0}, std::uint64_t{1}, a.count - 1}) {
      const double value = axis.value(std::min(probe, a.count - 1));
      const int states = probe_scene({{a.key, format_number(value)}}, option);
      if (states != d) {
        fail(option, a.key + " changes the dimension of the state (d = " + std::to_string(d) +
                         " to " + std::to_string(states) + "); it cannot vary in a sweep");
      }
    }
    axes.push_back(axis);
    parameter_axes.push_back(a);
  }
  if (parameter_axes.size() > 1) {
    for (const std::uint64_t probe : {std::uint64_t{0}, std::uint64_t{1}, ~std::uint64_t{0}}) {
      Params overrides;
      for (const SweepAxis& axis : axes) {
        if (axis.kind != SweepAxis::Kind::kParameter) continue;
        overrides.emplace_back(axis.parameter,
                               format_number(axis.value(std::min(probe, axis.count - 1))));
      }
      probe_scene(overrides, "--vary-param");
    }
  }
  std::unique_ptr<SweepGrid> grid;
  try {
    grid = std::make_unique<SweepGrid>(axes);
  } catch (const InvalidArgument& e) {
    fail("--vary", std::string(e.what()).substr(std::string("sweep: ").size()));
  }
  const Eigen::VectorXd x0 =
      request.x0_text ? parse_vector(*request.x0_text, "--x0", d) : default_x0;
  FlowSweepRequest sweep_request;
  sweep_request.t = request.t;
  sweep_request.flow = request.flow;
  for (std::size_t k = 0; k < request.dx_texts.size(); ++k) {
    sweep_request.directions.push_back(
        parse_vector(request.dx_texts[k], "--dx[" + std::to_string(k) + "]", d));
  }
  // Every file the command writes, with the option that names it: none may be another, and
  // none may be anything but a file it can replace.
  std::vector<std::pair<fs::path, std::string>> files;
  if (options.output) files.emplace_back(*options.output, "--output");
  if (options.atlas) {
    if (grid->axes().size() != 2) {
      fail("--atlas", "needs a grid of exactly two axes (--vary, --vary-param), got " +
                          std::to_string(grid->axes().size()));
    }
    if (sweep_request.directions.empty()) {
      fail("--atlas", "needs a --dx: the direction whose crossing orders it maps");
    }
    const fs::path png(*options.atlas);
    if (!png.has_filename()) fail("--atlas", quote(*options.atlas, 200) + " names no file");
    const fs::path dir = png.has_parent_path() ? png.parent_path() : ".";
    try {
      prepare_output_directory(dir, "sweep");
    } catch (const DemoError& e) {
      fail("--atlas", std::string(e.what()).substr(std::string("sweep: ").size()));
    }
    const std::string stem = png.stem().string();
    files.emplace_back(png, "--atlas");
    files.emplace_back(dir / (stem + ".dat"), "the atlas's data (--atlas)");
    files.emplace_back(dir / (stem + ".gp"), "the atlas's gnuplot script (--atlas)");
    for (std::size_t k = files.size() - 3; k < files.size(); ++k) {
      try {
        check_replaceable_file(files[k].first, "sweep");
      } catch (const DemoError& e) {
        fail("--atlas", std::string(e.what()).substr(std::string("sweep: ").size()));
      }
    }
  }
  for (std::size_t j = 1; j < files.size(); ++j) {
    for (std::size_t i = 0; i < j; ++i) {
      if (same_file(files[i].first, files[j].first)) {
        fail(files[i].second == "--output" ? "--output" : "--atlas",
             quote(files[i].first.string(), 200) + " is also " + files[j].second + " (" +
                 quote(files[j].first.string(), 200) + "); name another file");
      }
    }
  }
  bool varies_parameters = false;
  for (const SweepAxis& axis : grid->axes())
    varies_parameters |= axis.kind == SweepAxis::Kind::kParameter;

  if (options.resume && !options.output) fail("--resume", "needs --output FILE");
  // The sweep's identity, the output's first line: what --resume checks.
  OrderedJson identity = OrderedJson::object();
  identity["bflow"] = version_string().substr(std::string("bflow ").size());
  for (const auto& [key, value] : setup.head.items()) identity[key] = value;
  identity["max_steps"] = request.flow.integrator.max_steps;
  identity["x0"] = request.x0_text ? vector_json(x0) : OrderedJson(nullptr);
  OrderedJson directions_json = OrderedJson::array();
  for (const Eigen::VectorXd& dx : sweep_request.directions) {
    directions_json.push_back(vector_json(dx));
  }
  identity["dx"] = std::move(directions_json);

  // Under MPI every rank computes and rank 0 alone writes; the others hear from it whether its
  // file checks passed.
  const bool ranks = g_mpi != nullptr && g_mpi->size() > 1;
  const bool writes = !ranks || g_mpi->rank() == 0;
  std::unique_ptr<std::FILE, int (*)(std::FILE*)> file(nullptr, &std::fclose);
  std::unique_ptr<StdioOutputBuffer> file_buffer;
  std::ostream file_stream(nullptr);
  std::ostream& records = options.output ? file_stream : out;
  SweepWriter writer(records, format, *grid, d, static_cast<int>(sweep_request.directions.size()),
                     identity.dump());
  SweepResumePoint kept;
  if (writes) try {
      if (options.output) {
        const std::string& path = *options.output;
        if (options.resume) kept = resume_point(path, writer);
        std::error_code code;
        if (kept.bytes > 0) fs::resize_file(path, kept.bytes, code);
        if (code) fail("--output", "cannot truncate " + quote(path, 200) + ": " + code.message());
        errno = 0;
        file.reset(std::fopen(path.c_str(), kept.bytes > 0 ? "ab" : "wb"));
        if (!file) {
          fail("--output", "cannot write " + quote(path, 200) + ": " + std::strerror(errno));
        }
        file_buffer = std::make_unique<StdioOutputBuffer>(file.get());
        file_stream.rdbuf(file_buffer.get());
        if (options.resume) {
          err << "sweep: " << kept.records << " of " << grid->samples() << " samples kept from "
              << quote(path, 200) << ", resuming at index " << kept.records << '\n';
        }
      }
      if (kept.bytes == 0) writer.header();
    } catch (...) {
      if (ranks) g_mpi->agree(false);
      throw;
    }
  if (ranks && !g_mpi->agree(true)) return kExitFailure;  // rank 0 reported why
  // A record that cannot be written ends the sweep, with the reason (a full disk, a closed
  // pipe) in the documented form.
  const auto check_written = [&]() {
    if (records) return;
    int error_number = 0;
    if (const auto* buffer = dynamic_cast<const StdioOutputBuffer*>(records.rdbuf())) {
      error_number = buffer->error_number();
    }
    const std::string why = error_number != 0 ? std::strerror(error_number) : "an I/O error";
    throw WriteError(options.output
                         ? "--output: cannot write " + quote(*options.output, 200) + ": " + why
                         : "stdout: write failed (" + why + ")");
  };
  const std::uint64_t first = kept.records;

  // The start: --x0, or the scene's own for the sample's parameters; then the varied states.
  const auto evaluate_sample = [&](const SegmentModel& model, const Eigen::VectorXd& scene_x0,
                                   std::uint64_t i) {
    Eigen::VectorXd start = request.x0_text ? x0 : scene_x0;
    grid->apply_states(i, start);
    return evaluate_flow_sample(model, start, sweep_request, i, grid->values(i));
  };
  // The workers format their records too; the writing thread only copies the lines.
  struct Formatted {
    std::string status, line;
    AtlasPoint point;
  };
  std::vector<AtlasPoint> atlas;
  const auto atlas_point = [&](const FlowSampleRecord& r) {
    AtlasPoint p;
    if (!options.atlas) return p;
    p.x = r.varied.at(0);
    p.y = r.varied.at(1);
    p.structure = event_structure(r);
    p.failed = !r.ok();
    for (const EventRecord& e : r.events) p.grouped |= r.ok() && e.group_size() > 1;
    return p;
  };
  const auto run = [&](const std::function<FlowSampleRecord(std::uint64_t)>& evaluate) {
    std::map<std::string, std::uint64_t> counts;
    std::vector<std::uint64_t> per_rank;
    SweepRunOptions o;
    o.threads = threads;
    if (!options.quiet) o.progress = [&err](const SweepProgress& p) { draw_progress(err, p); };
    const auto formatted = [&](const FlowSampleRecord& r) {
      return Formatted{r.status, writer.line(r), atlas_point(r)};
    };
    const auto take = [&](Formatted&& f) {
      records << f.line;
      ++counts[f.status];
      if (options.atlas) atlas.push_back(std::move(f.point));
      check_written();
    };
    if (ranks) {
      // A record travels as status, structure, grouped, failed and line, separated by \x1f
      // (none of them holds it); rank 0 takes x and y of the atlas from the grid.
      std::uint64_t index = first;
      per_rank = run_ordered_mpi(
          *g_mpi, first, grid->samples(),
          [&](std::uint64_t i) {
            FlowSampleRecord r;
            try {
              r = evaluate(i);
            } catch (const std::exception& e) {
              r = FlowSampleRecord::error(i, grid->values(i), e.what());
            }
            const Formatted f = formatted(r);
            return f.status + '\x1f' + f.point.structure + '\x1f' + (f.point.grouped ? "1" : "0") +
                   '\x1f' + (f.point.failed ? "1" : "0") + '\x1f' + f.line;
          },
          [&](std::string&& bytes) {
            Formatted f;
            std::size_t at = 0;
            const auto field = [&]() {
              const std::size_t stop = bytes.find('\x1f', at);
              std::string text = bytes.substr(at, stop - at);
              at = stop + 1;
              return text;
            };
            f.status = field();
            f.point.structure = field();
            f.point.grouped = field() == "1";
            f.point.failed = field() == "1";
            f.line = bytes.substr(at);
            if (options.atlas) {
              const std::vector<double> v = grid->values(index);
              f.point.x = v.at(0);
              f.point.y = v.at(1);
            }
            ++index;
            take(std::move(f));
          },
          o);
    } else {
      run_ordered<Formatted>(
          first, grid->samples(), [&](std::uint64_t i) { return formatted(evaluate(i)); },
          [&](std::uint64_t i, const std::string& what) {
            return formatted(FlowSampleRecord::error(i, grid->values(i), what));
          },
          take, o);
    }
    if (!writes) return;
    records.flush();
    check_written();
    if (file && std::fflush(file.get()) != 0) {
      throw WriteError("--output: cannot write " + quote(*options.output, 200) + ": " +
                       std::strerror(errno));
    }
    std::string summary = "sweep: " + std::to_string(grid->samples() - first) + " samples";
    for (const auto& [status, count] : counts)
      summary += ", " + std::to_string(count) + " " + status;
    if (ranks) {
      summary += "; computed by ranks 0.." + std::to_string(per_rank.size() - 1) + ":";
      for (std::size_t r = 0; r < per_rank.size(); ++r) {
        summary += (r == 0 ? " " : ", ") + std::to_string(per_rank[r]);
      }
    }
    err << summary << '\n';
  };
  const auto finish_atlas = [&]() {
    if (!options.atlas || !writes) return;
    if (first > 0) {
      err << "sweep: the atlas shows the samples of this run only (from index " << first << ")\n";
    }
    draw_atlas(*options.atlas, *grid, atlas, sweep_request.directions.front());
    err << "sweep: wrote " << quote(*options.atlas, 200) << '\n';
  };
  if (!varies_parameters) {
    // One model serves every sample (its evaluations are const and thread-safe).
    with_scene(setup, {}, [&](const SegmentModel& model, const Eigen::VectorXd& scene_x0) {
      run([&](std::uint64_t i) { return evaluate_sample(model, scene_x0, i); });
      return 0;
    });
  } else {
    run([&](std::uint64_t i) {
      Params overrides;
      const std::vector<double> values = grid->values(i);
      for (std::size_t a = 0; a < grid->axes().size(); ++a) {
        if (grid->axes()[a].kind == SweepAxis::Kind::kParameter)
          overrides.emplace_back(grid->axes()[a].parameter, format_number(values[a]));
      }
      return with_scene(setup, overrides,
                        [&](const SegmentModel& model, const Eigen::VectorXd& scene_x0) {
                          return evaluate_sample(model, scene_x0, i);
                        });
    });
  }
  if (file && std::fclose(file.release()) != 0) {
    throw WriteError("--output: cannot write " + quote(*options.output, 200) + ": " +
                     std::strerror(errno));
  }
  finish_atlas();
  return kExitOk;
}

int run_sweep_on(const SweepCommandOptions& options, std::ostream& out, std::ostream& err) {
  try {
    return sweep_command(options, out, err);
  } catch (const InputError& e) {
    report_error(err, e.what());
    return kExitBadInput;
  } catch (const WriteError& e) {
    report_error(err, e.what());
    return kExitFailure;
  } catch (const InvalidArgument& e) {
    // The sweep library's own messages already name it.
    const std::string what = e.what();
    report_error(err, what.rfind("sweep: ", 0) == 0 ? what : "sweep: " + what);
    return kExitBadInput;
  } catch (const DemoError& e) {  // the atlas could not be written or drawn
    report_error(err, e.what());
    return kExitFailure;
  } catch (const std::bad_alloc&) {
    report_error(err, "sweep: out of memory");
    return kExitFailure;
  } catch (const std::exception& e) {
    report_error(err, std::string("sweep: ") + e.what());
    return kExitFailure;
  }
}

}  // namespace

void set_mpi_session(const MpiSession* session) { g_mpi = session; }

int run_sweep(const SweepCommandOptions& options, std::ostream& out, std::ostream& err) {
  // Ranks other than 0 write nothing: rank 0 writes the records, the progress and any error.
  std::ostream null_stream(nullptr);
  const bool quiet_rank = g_mpi != nullptr && g_mpi->size() > 1 && g_mpi->rank() != 0;
  std::ostream& err_stream = quiet_rank ? null_stream : err;
  return run_sweep_on(options, quiet_rank ? null_stream : out, err_stream);
}

}  // namespace bflow::cli
