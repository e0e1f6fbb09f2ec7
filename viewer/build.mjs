// Bundle the viewer (src/main.js + three.js) into the one minified script the Python package ships.
// three.js's loaders can fetch from the network (FileLoader, ImageBitmapLoader); the page only ever
// parses bytes it holds, and its policy forbids requests, but the bundle should not even contain a
// call that could: every `fetch(` in three.js's modules is rewritten to `ncflowNoNetwork(`, a function
// main.js defines that rejects.
import { readFile } from "node:fs/promises";
import * as esbuild from "esbuild";

const offline = {
  name: "offline",
  setup(build) {
    build.onLoad({ filter: /[\\/]node_modules[\\/]three[\\/].*\.js$/ }, async (args) => {
      const text = await readFile(args.path, "utf8");
      return { contents: text.replace(/\bfetch\s*\(/g, "ncflowNoNetwork("), loader: "js" };
    });
  },
};

await esbuild.build({
  entryPoints: ["src/main.js"],
  bundle: true,
  minify: true,
  format: "iife",
  target: "es2020",
  platform: "browser",
  legalComments: "eof",
  charset: "ascii",
  logLevel: "warning",
  outfile: process.argv[2],
  plugins: [offline],
});
