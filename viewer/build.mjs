// Bundles src/ into dist/ with esbuild. zenoh-ts ships its key-expression code as wasm-bindgen
// "bundler" output (`import * as wasm from "./x_bg.wasm"`, the ESM-integration proposal), which
// esbuild does not implement; the plugin below rewrites such a module to instantiate the wasm
// bytes itself (top-level await) with the `_bg.js` glue as its imports, which is what a
// wasm-aware bundler generates.
import { build } from "esbuild";
import { copyFile, mkdir, readFile } from "node:fs/promises";
import path from "node:path";

const wasmBindgenModules = {
  name: "wasm-bindgen-bundler-target",
  setup(b) {
    b.onLoad({ filter: /zenoh-ts[\\/]dist[\\/].*\.js$/ }, async (args) => {
      const source = await readFile(args.path, "utf8");
      const m = source.match(/import \* as wasm from "(\.\/[^"]+_bg\.wasm)";/);
      if (!m) return undefined;
      const glue = m[1].replace(/\.wasm$/, ".js");
      const rewritten = source
        .replace(m[0], `import wasmBytes from "${m[1]}";\nimport * as __glue from "${glue}";\n` +
          `const { instance: __instance } = await WebAssembly.instantiate(wasmBytes, ` +
          `{ "${glue}": __glue });\nconst wasm = __instance.exports;`);
      return { contents: rewritten, loader: "js", resolveDir: path.dirname(args.path) };
    });
  },
};

await mkdir("dist", { recursive: true });
await build({
  entryPoints: ["src/main.js"],
  bundle: true,
  format: "esm",
  target: "es2022",
  outfile: "dist/viewer.js",
  loader: { ".wasm": "binary" },
  plugins: [wasmBindgenModules],
  logLevel: "warning",
});
await copyFile("src/index.html", "dist/index.html");
console.log("viewer built: dist/index.html, dist/viewer.js");
