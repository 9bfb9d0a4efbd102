// `pstream export clip.pstream --out DIR | -o NAME.abc | -o NAME.ply`: arguments and printing around
// cook::export_clip().
#include <filesystem>
#include <tuple>

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include "cli_terms.hpp"
#include "commands.hpp"
#include "particlestream/cook.hpp"
#include "particlestream/error.hpp"
#include "progress.hpp"

namespace pstream::app {

int run_export(const ExportCli& cli) {
  if (cli.out.empty() == cli.output.empty())
    throw Error("export: give either --out DIR (a PLY sequence) or -o FILE.abc (an Alembic cache)");
  cook::ExportOptions o;
  o.input = cli.file;
  o.output = cli.out.empty() ? std::filesystem::path(cli.output) : std::filesystem::path(cli.out) / "frame.ply";
  if (!cli.frames.empty()) std::tie(o.frame_begin, o.frame_end) = parse_frame_range(cli.frames);
  ProgressBar bar("export", !cli.quiet && !cli.json);
  const cook::ExportReport r =
      cook::export_clip(o, [&](std::uint64_t done, std::uint64_t total) { bar.update(done, total, "frames"); });
  if (cli.json) {
    const nlohmann::ordered_json j{{"input", cli.file},
                                   {"format", r.ply ? "ply" : "alembic"},
                                   {"frames", r.frames},
                                   {"first", r.first.string()},
                                   {"bytes_written", r.bytes_written}};
    fmt::print("{}\n", j.dump(2));
  } else if (!cli.quiet) {
    fmt::print("{} -> {}{}\n", count_of(r.frames, "frame"), r.first.string(), r.ply && r.frames > 1 ? " ..." : "");
  }
  return 0;
}

}  // namespace pstream::app
