// The simplest alternative a lab would build: a Node `ws` server that re-broadcasts every message
// it gets to every other connected client (the broadcast example of the ws README, unchanged).
//   node relay.mjs PORT
import {WebSocketServer, WebSocket} from 'ws';

const wss = new WebSocketServer({host: '127.0.0.1', port: Number(process.argv[2])});
wss.on('connection', function connection(ws) {
  ws.on('message', function message(data, isBinary) {
    wss.clients.forEach(function each(client) {
      if (client !== ws && client.readyState === WebSocket.OPEN) client.send(data, {binary: isBinary});
    });
  });
});
wss.on('listening', () => console.log('relay listening'));
