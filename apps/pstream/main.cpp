// pstream: the ParticleStream command-line tool.
#include <cstdio>
#include <exception>

#include <CLI/CLI.hpp>
#include <fmt/format.h>

#include "commands.hpp"
#include "particlestream/error.hpp"

int main(int argc, char** argv) {
  using namespace pstream::app;
  CLI::App app{
      "pstream — play back pre-simulated particle caches in real time.\n\n"
      "Examples:\n"
      "  pstream info sim.abc            summary of an Alembic point cache\n"
      "  pstream info sim.abc --json     every value, in the alembic-fixture-expected/1 schema\n"
      "  pstream bench read sim.abc      cost of reading every frame vs. a plain memcpy",
      "pstream"};
  app.require_subcommand(1);
  app.set_version_flag("--version", "pstream 0.1.0");

  InfoOptions info;
  auto* info_cmd = app.add_subcommand("info", "Describe a file: time samplings, objects, particle counts, attributes");
  info_cmd->add_option("file", info.file, "An Alembic (.abc, Ogawa) file")->required()->check(CLI::ExistingFile);
  info_cmd->add_flag("--json", info.json,
                     "Print a JSON document in the alembic-fixture-expected/1 schema (see docs/alembic.md), "
                     "comparable value by value with the official Alembic library's answers");

  auto* bench_cmd = app.add_subcommand("bench", "Measure a stage against a baseline run side by side");
  bench_cmd->require_subcommand(1);
  BenchReadOptions bench_read_opts;
  auto* read_cmd = bench_cmd->add_subcommand(
      "read", "Read every frame's positions into a caller buffer, compared with memcpy of the same mapped bytes");
  read_cmd->add_option("file", bench_read_opts.file, "An Alembic file")->required()->check(CLI::ExistingFile);
  read_cmd->add_option("--object", bench_read_opts.object, "Full name of the points object (default: the largest)");
  read_cmd->add_option("--repetitions", bench_read_opts.repetitions, "Passes over all frames; medians are reported")
      ->check(CLI::Range(1, 10000));
  read_cmd->add_flag("--json", bench_read_opts.json, R"(Print {"read_ms":…, "memcpy_ms":…, "ratio":…})");

  CLI11_PARSE(app, argc, argv);
  try {
    if (info_cmd->parsed()) return info_alembic(info);
    if (read_cmd->parsed()) return bench_read(bench_read_opts);
  } catch (const pstream::Error& e) {
    fmt::print(stderr, "pstream: error: {}\n", e.what());
    return 1;
  } catch (const std::exception& e) {
    fmt::print(stderr, "pstream: internal error: {}\n", e.what());
    return 2;
  }
  return 0;
}
