#!/usr/bin/env bash
# Builds the docs site into DIR (default target/site): docs/*.md, the README
# as its home page, and the API reference from the docstrings and stubs
# (mkdocs + mkdocstrings, mkdocs.yml). Strict: a warning (a broken link, a
# page left out of the navigation, a docstring mkdocstrings cannot read)
# fails the build. Open DIR/index.html. Runs scripts/setup.sh first unless
# SENSAUG_SKIP_SETUP=1 (mkdocs is in requirements-dev.txt).
set -euo pipefail
cd "$(dirname "$0")/.."
[ "${SENSAUG_SKIP_SETUP:-0}" = 1 ] || bash scripts/setup.sh
SITE=$(realpath -m "${1:-target/site}")
SRC=target/docs-src
rm -rf "$SRC"
mkdir -p "$SRC"
cp docs/*.md docs/*.png docs/*.json "$SRC"/  # pages, their pictures and files they link
# The README links docs/X.md from the repository root; on the site the pages
# sit beside it.
sed -e 's#(docs/\([A-Za-z0-9_]*\.md\)#(\1#g' README.md > "$SRC/index.md"
.venv/bin/python -m mkdocs build --strict --clean -f mkdocs.yml -d "$SITE"
echo "docs site: $SITE/index.html"
