// Parse a tileset with 3d-tiles-tools (npm): traverse every tile, resolve every content URI and identify its
// content type. `node tests/js/parse_tileset.mjs path/to/tileset.json` prints
// {tiles, contents, contentTypes: {type: n}, unresolved: [...]} and exits 1 on any failure.
import fs from 'node:fs';
import path from 'node:path';
import { ContentDataTypeRegistry, ResourceResolvers, TilesetTraverser, BufferedContentData } from '3d-tiles-tools';

const file = path.resolve(process.argv[2]);
const dir = path.dirname(file);
const tileset = JSON.parse(fs.readFileSync(file, 'utf8'));
const resolver = ResourceResolvers.createFileResourceResolver(dir);
const traverser = new TilesetTraverser(dir, resolver, { depthFirst: false, traverseExternalTilesets: true });
const out = { tiles: 0, contents: 0, contentTypes: {}, unresolved: [] };
await traverser.traverse(tileset, async (traversedTile) => {
  out.tiles += 1;
  for (const content of traversedTile.getRawContents()) {
    out.contents += 1;
    const data = await resolver.resolveData(content.uri);
    if (!data) {
      out.unresolved.push(content.uri);
      continue;
    }
    const type = await ContentDataTypeRegistry.findContentDataType(new BufferedContentData(content.uri, data));
    out.contentTypes[type] = (out.contentTypes[type] || 0) + 1;
  }
  return true;
});
console.log(JSON.stringify(out));
process.exit(out.unresolved.length || out.tiles === 0 ? 1 : 0);
