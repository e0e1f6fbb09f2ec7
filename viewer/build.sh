#!/bin/sh
# Bundle the viewer (src/main.js + three.js with its glTF loader) into the one minified script that the
# Python package ships: ../src/ncflow/view/assets/viewer.js, plus three.js's licence beside it.
# Run from this folder after `npm ci` (pinned versions in package-lock.json): `npm run build`.
set -eu
cd "$(dirname "$0")"
ASSETS=../src/ncflow/view/assets
mkdir -p "$ASSETS"
node build.mjs "$ASSETS/viewer.js"  # esbuild, three.js's fetch calls rewritten (see build.mjs)
THREE_VERSION=$(node -p "require('./node_modules/three/package.json').version")
{
  echo "Third-party software bundled in viewer.js (the page script of \`ncflow view\`)"
  echo
  echo "three.js $THREE_VERSION (https://threejs.org), MIT licence:"
  echo
  cat node_modules/three/LICENSE
} > "$ASSETS/THIRD_PARTY_LICENSES.txt"
if grep -qi "</script" "$ASSETS/viewer.js"; then
  echo "build.sh: the bundle contains '</script' and cannot be inlined in a page" >&2
  exit 1
fi
ls -l "$ASSETS/viewer.js"
