// Parse a tileset with 3d-tiles-tools (npm): traverse every tile (an implicit tileset's subtrees included),
// resolve every content URI and identify its content type. `node tests/js/parse_tileset.mjs path/to/tileset.json`
// prints {tiles, contents, contentTypes: {type: n}, unresolved: [...], implicit, subtrees,
// final: {uri: [geometricError, region]}} and exits 1 on any failure. An implicit tileset's root (the tile with
// implicitTiling, whose content URI is the template) is not a tile of the tree: it is not counted; `final` is
// each content's tile after 3d-tiles-tools applied the subtree tile metadata (TILE_BOUNDING_REGION,
// TILE_GEOMETRIC_ERROR).
import fs from 'node:fs';
import path from 'node:path';
import { ContentDataTypeRegistry, ResourceResolvers, TilesetTraverser, BufferedContentData } from '3d-tiles-tools';

const file = path.resolve(process.argv[2]);
const dir = path.dirname(file);
const tileset = JSON.parse(fs.readFileSync(file, 'utf8'));
const resolver = ResourceResolvers.createFileResourceResolver(dir);
const traverser = new TilesetTraverser(dir, resolver, { depthFirst: false, traverseExternalTilesets: true });
const out = { tiles: 0, contents: 0, contentTypes: {}, unresolved: [], implicit: false, subtrees: 0, final: {} };
const subtrees = new Set();
await traverser.traverse(tileset, async (traversedTile) => {
  if (traversedTile.isImplicitTilesetRoot()) {
    out.implicit = true;
    return true;
  }
  const subtree = traversedTile.getSubtreeUri();
  if (subtree) subtrees.add(subtree);
  out.tiles += 1;
  const finalTile = traversedTile.asFinalTile();
  for (const content of traversedTile.getFinalContents()) {
    out.contents += 1;
    out.final[content.uri] = [finalTile.geometricError, (finalTile.boundingVolume || {}).region || null];
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
out.subtrees = subtrees.size;
console.log(JSON.stringify(out));
process.exit(out.unresolved.length || out.tiles === 0 ? 1 : 0);
