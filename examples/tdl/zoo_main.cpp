// tdl: topological deep learning on TopoNetX/TopoModelX-style cases (temporary main with the
// model-zoo subcommands, until it joins the tdl program's main).
#include "zoo_commands.hpp"

#include <iostream>

int main(int argc, char** argv) {
  CLI::App app("tdl: TopoModelX models on topos");
  app.require_subcommand(1);
  tdl_program::add_forward_command(app);
  tdl_program::add_grad_command(app);
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e);
  } catch (const std::exception& e) {
    std::cerr << "tdl: " << e.what() << "\n";
    return 1;
  }
  return 0;
}
