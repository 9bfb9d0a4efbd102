// The names the render options are given by (in files, on command lines, in the Python API).
#include <fmt/format.h>

#include "particlestream/render.hpp"

namespace pstream::render {

BlendMode parse_blend(const std::string& name) {
  if (name == "alpha") return BlendMode::Alpha;
  if (name == "additive") return BlendMode::Additive;
  if (name == "alphatest") return BlendMode::AlphaTest;
  throw Error(fmt::format("blend mode '{}': expected alpha, additive or alphatest", name));
}

Look parse_look(const std::string& name) {
  if (name == "sprites") return Look::Sprites;
  if (name == "liquid") return Look::Liquid;
  throw Error(fmt::format("look '{}': expected sprites or liquid", name));
}

LiquidFilter parse_liquid_filter(const std::string& name) {
  if (name == "narrow-range") return LiquidFilter::NarrowRange;
  if (name == "bilateral") return LiquidFilter::Bilateral;
  if (name == "gaussian") return LiquidFilter::Gaussian;
  if (name == "none") return LiquidFilter::None;
  throw Error(fmt::format("liquid filter '{}': expected narrow-range, bilateral, gaussian or none", name));
}

LiquidOutput parse_liquid_output(const std::string& name) {
  if (name == "shaded") return LiquidOutput::Shaded;
  if (name == "depth") return LiquidOutput::Depth;
  if (name == "normals") return LiquidOutput::Normals;
  if (name == "thickness") return LiquidOutput::Thickness;
  throw Error(fmt::format("liquid output '{}': expected shaded, depth, normals or thickness", name));
}

}  // namespace pstream::render
